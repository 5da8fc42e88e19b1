"""What the two spectrogram trackers (``spec-cnn2d``, ``seldnet``) share: their input."""
from __future__ import annotations

from typing import TYPE_CHECKING, Mapping

import doabench
from doabench.errors import ConfigError

from .neural import NeuralTracker

if TYPE_CHECKING:
    import torch


#: The observation kind each ``phase`` option reads: each microphone's own phase (the paper's text)
#: or its phase relative to the first microphone's (:func:`doabench.features.spectrogram_features`).
PHASE_KINDS = {"absolute": "spectrogram", "relative": "spectrogram_ipd"}


class SpectrogramTracker(NeuralTracker):
    """A tracker on magnitude and phase spectrograms ``(2 n_mics, window / 2)`` per frame."""

    observation_spec = doabench.ObservationSpec.of(("spectrogram",))
    #: the paper trains its spectrogram models in rooms with T60 in [0, 0.3] s (section V-A)
    training_defaults = {"t60": (0.0, 0.3)}

    def __init__(self, spec: str | None = None, weights: str | None = None, device: str = "cpu",
                 seed: int = 0, resolution: str | None = None, array: str | None = None,
                 hold: str | int = "auto", phase: str = "auto") -> None:
        """The :class:`NeuralTracker` options, and ``phase``: the phase channels the network reads,
        ``absolute`` (each microphone's own phase, the paper's text), ``relative`` (minus the first
        microphone's) or ``auto`` (the weights' own; ``absolute`` for random weights). Weights
        trained on one are refused with the other."""
        if phase not in ("auto", *PHASE_KINDS):
            raise ConfigError(f"tracker option phase must be auto, {' or '.join(PHASE_KINDS)}, got {phase!r}")
        self._phase_option = phase
        super().__init__(spec, weights=weights, device=device, seed=seed, resolution=resolution, array=array, hold=hold)
        self.options.update(phase=phase)

    def _own_observations(self) -> doabench.ObservationSpec:
        declared = type(self).observation_spec
        if self.weights_file is None:
            kind = PHASE_KINDS["absolute" if self._phase_option == "auto" else self._phase_option]
            return doabench.ObservationSpec.of((kind,), None, declared.frame_spec,
                                               spectrogram_frame_spec=declared.spectrogram_frame_spec)
        stored = self.weights_file.observations
        allowed = PHASE_KINDS if self._phase_option == "auto" else {self._phase_option: PHASE_KINDS[self._phase_option]}
        if stored.kind_names not in [(kind,) for kind in allowed.values()]:
            wanted = " or ".join(allowed.values())
            raise ConfigError(f"weights file {self.weights_file.path.name} was trained on {stored}, not on the kind "
                              f"{self.model_name} reads with phase={self._phase_option} ({wanted})")
        return stored

    @property
    def network_features(self) -> tuple[str, ...]:
        """The one spectrogram kind its ``phase`` reads."""
        return self.observation_spec.kind_names

    @property
    def phase(self) -> str:
        """The phase channels it reads: ``absolute`` or ``relative``."""
        kind = self.observation_spec.kind_names[0]
        return next(p for p, k in PHASE_KINDS.items() if k == kind)

    def _spec_shape(self) -> tuple[int, int]:
        return (2 * self._array.n_mics, self.frame_spec.window // 2)

    def check_array_fits(self, array: doabench.MicArray) -> None:
        if 2 * array.n_mics != self._spec_shape()[0]:
            raise ConfigError(f"tracker {self.name!r} was built for {self._array.n_mics} microphones "
                              f"(array {self._array.name!r}); array {array.name!r} has {array.n_mics}: "
                              "pass --tracker-opt array=NAME_OR_FILE")

    def network_input(self, features: Mapping[str, torch.Tensor]) -> torch.Tensor:
        s = features[self.observation_spec.kind_names[0]]  # (B, T, 2 n_mics, bins)
        if tuple(s.shape[2:]) != self._spec_shape():
            raise ConfigError(f"tracker {self.name!r} expects spectrograms of shape {self._spec_shape()}, "
                              f"got {tuple(s.shape[2:])}")
        return s.transpose(1, 2)  # (B, 2 n_mics, T, bins)
