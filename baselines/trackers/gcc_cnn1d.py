"""``gcc-cnn1d``: a 1D CNN over the GCC-PHAT values within the physical lag range (paper V-A)."""
from __future__ import annotations

from typing import TYPE_CHECKING, Mapping

import doabench
from doabench.errors import ConfigError

from .neural import NeuralTracker

if TYPE_CHECKING:
    import torch
    from torch import nn


def _n_lags(array: doabench.MicArray, fs: int) -> int:
    return 2 * array.max_lag(fs) + 1


@doabench.register_tracker("gcc-cnn1d")
class GccCnn1dTracker(NeuralTracker):
    """1D CNN over the GCC-PHAT values within the physical lag range (paper V-A)."""

    model_name = "gcc-cnn1d"
    observation_spec = doabench.ObservationSpec.of(("gcc",))

    def build_model(self) -> nn.Module:
        from ..cnn1d import CausalCnn1d

        self._gcc_shape = (len(self._array.pairs), _n_lags(self._array, self.frame_spec.fs))
        return CausalCnn1d(self._gcc_shape[0] * self._gcc_shape[1])

    def check_array_fits(self, array: doabench.MicArray) -> None:
        shape = (len(array.pairs), _n_lags(array, self.frame_spec.fs))
        if shape != self._gcc_shape:
            raise ConfigError(f"tracker {self.name!r} was built for array {self._array.name!r} "
                              f"({self._gcc_shape[0]} pairs x {self._gcc_shape[1]} lags); array {array.name!r} "
                              f"gives {shape[0]} x {shape[1]}: pass --tracker-opt array=NAME_OR_FILE")

    def network_input(self, features: Mapping[str, torch.Tensor]) -> torch.Tensor:
        gcc = features["gcc"]  # (B, T, n_pairs, n_lags)
        if tuple(gcc.shape[2:]) != self._gcc_shape:
            raise ConfigError(f"tracker {self.name!r} expects gcc of shape {self._gcc_shape}, "
                              f"got {tuple(gcc.shape[2:])}")
        return gcc.flatten(2).transpose(1, 2)  # (B, n_pairs * n_lags, T), pair-major
