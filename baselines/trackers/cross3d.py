"""``cross3d``: Cross3D (paper IV-B) on SRP-PHAT maps and their maxima."""
from __future__ import annotations

from typing import TYPE_CHECKING, Mapping

import doabench
from doabench.errors import ConfigError

from .. import catalog
from ..weights import resolution_text
from .neural import NeuralTracker

if TYPE_CHECKING:
    import torch
    from torch import nn


@doabench.register_tracker("cross3d")
class Cross3DTracker(NeuralTracker):
    """Cross3D (paper IV-B) on SRP-PHAT maps and their maxima; spec = map resolution."""

    model_name = "cross3d"
    features = ("srp", "srp_max")
    uses_resolution = True

    def _default_resolution(self) -> tuple[int, int]:
        """The catalog's default resolution for ``cross3d`` (its default rule), else 8x16."""
        return catalog.default_resolution(self.model_name) or (8, 16)

    def build_model(self) -> nn.Module:
        from ..cross3d import Cross3D

        return Cross3D(*self._resolution)

    def network_input(self, features: Mapping[str, torch.Tensor]) -> torch.Tensor:
        srp = features["srp"]  # (B, T, n_theta, n_phi)
        if tuple(srp.shape[2:]) != self._resolution:
            raise ConfigError(f"tracker {self.name!r} expects {resolution_text(self._resolution)} maps, "
                              f"got {'x'.join(map(str, srp.shape[2:]))}")
        from ..cross3d import cross3d_input

        x = cross3d_input(srp, features["srp_max"])  # (B, T, 3, n_theta, n_phi)
        return x.transpose(1, 2)
