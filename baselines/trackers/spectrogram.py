"""What the two spectrogram trackers (``spec-cnn2d``, ``seldnet``) share: their input."""
from __future__ import annotations

from typing import TYPE_CHECKING, Mapping

import doabench
from doabench.errors import ConfigError

from .neural import NeuralTracker

if TYPE_CHECKING:
    import torch


class SpectrogramTracker(NeuralTracker):
    """A tracker on magnitude and phase spectrograms ``(2 n_mics, window / 2)`` per frame."""

    observation_spec = doabench.ObservationSpec.of(("spectrogram",))
    #: the paper trains its spectrogram models in rooms with T60 in [0, 0.3] s (section V-A)
    training_defaults = {"t60": (0.0, 0.3)}

    def _spec_shape(self) -> tuple[int, int]:
        return (2 * self._array.n_mics, self.frame_spec.window // 2)

    def check_array_fits(self, array: doabench.MicArray) -> None:
        if 2 * array.n_mics != self._spec_shape()[0]:
            raise ConfigError(f"tracker {self.name!r} was built for {self._array.n_mics} microphones "
                              f"(array {self._array.name!r}); array {array.name!r} has {array.n_mics}: "
                              "pass --tracker-opt array=NAME_OR_FILE")

    def network_input(self, features: Mapping[str, torch.Tensor]) -> torch.Tensor:
        s = features["spectrogram"]  # (B, T, 2 n_mics, bins)
        if tuple(s.shape[2:]) != self._spec_shape():
            raise ConfigError(f"tracker {self.name!r} expects spectrograms of shape {self._spec_shape()}, "
                              f"got {tuple(s.shape[2:])}")
        return s.transpose(1, 2)  # (B, 2 n_mics, T, bins)
