"""``max-cnn1d``: a 1D CNN over the normalised coordinates of each SRP map's maximum (paper V-A)."""
from __future__ import annotations

from typing import TYPE_CHECKING, Mapping

import doabench

from .neural import NeuralTracker

if TYPE_CHECKING:
    import torch
    from torch import nn


@doabench.register_tracker("max-cnn1d")
class MaxCnn1dTracker(NeuralTracker):
    """1D CNN over the normalised coordinates of each map's maximum (paper V-A); spec = resolution."""

    model_name = "max-cnn1d"
    observation_spec = doabench.ObservationSpec.of(("srp_max",), (64, 128))
    uses_resolution = True

    def _default_resolution(self) -> tuple[int, int]:
        return (64, 128)

    def build_model(self) -> nn.Module:
        from ..cnn1d import CausalCnn1d

        return CausalCnn1d(2)

    def network_input(self, features: Mapping[str, torch.Tensor]) -> torch.Tensor:
        return features["srp_max"].transpose(1, 2)  # (B, T, 2) -> (B, 2, T)
