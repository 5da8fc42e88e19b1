"""``cross3d``: Cross3D (paper IV-B) on SRP-PHAT maps and their maxima."""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

import doabench
from doabench.errors import ConfigError

from .. import catalog
from ..refine import MapRefiner, parse_radius, parse_refine, parse_speed
from ..weights import resolution_text
from .neural import NeuralTracker

if TYPE_CHECKING:
    import torch
    from torch import nn


@doabench.register_tracker("cross3d")
class Cross3DTracker(NeuralTracker):
    """Cross3D (paper IV-B) on SRP-PHAT maps and their maxima; spec = map resolution."""

    model_name = "cross3d"
    observation_spec = doabench.ObservationSpec.of(("srp", "srp_max"))
    uses_resolution = True

    def __init__(self, spec: str | None = None, weights: str | None = None, device: str = "cpu",
                 seed: int = 0, resolution: str | None = None, array: str | None = None,
                 hold: str | int = "auto", refine: str = "off", refine_radius: str | float = "auto",
                 refine_speed: str | float = 0) -> None:
        """The :class:`NeuralTracker` options, and ``refine``: ``off`` (the paper's output) or a finer
        map resolution (``64x128``) whose maximum within ``refine_radius`` degrees (``auto``: one
        cell of the network's map) replaces the direction on voice-active frames, only where the
        network's direction turns faster than ``refine_speed`` degrees per second (0: on every one)
        (:mod:`doabench_baselines.refine`)."""
        fine = parse_refine(refine)
        speed = parse_speed(refine_speed)
        if speed > 0 and fine is None:  # it would name a run apart from the plain one it equals
            raise ConfigError(f"refine_speed={refine_speed} gates refine, which is off: add refine=64x128 (or leave it out)")
        super().__init__(spec, weights=weights, device=device, seed=seed, resolution=resolution, array=array, hold=hold)
        self.options.update(refine=refine, refine_radius=refine_radius, refine_speed=refine_speed)
        self._refine_grid = fine
        self._refine_radius = parse_radius(refine_radius, self._resolution, self._array.planar) if fine else None
        self._refine_speed = speed
        self._refiner: MapRefiner | None = None
        if fine is not None:
            # the fine map is computed from the frame's audio
            self.observation_spec = self.observation_spec.with_kinds(doabench.ConfiguredKind.of("audio"))

    def reset(self, array: doabench.MicArray, **context: Any) -> None:
        super().reset(array, **context)
        if self._refine_grid is not None:
            self._refiner = MapRefiner(array, self._refine_grid, self.frame_spec, self._refine_radius,
                                       self._refine_speed)

    @property
    def refines(self) -> bool:
        return self._refine_grid is not None

    def refine(self, directions: np.ndarray, observations: Mapping[str, np.ndarray]) -> np.ndarray:
        if not self.refines:
            return directions
        if self._refiner is None:
            raise ConfigError(f"tracker {self.name!r}: reset(array) before running it (refine needs the array)")
        return self._refiner.episode(directions, observations)

    def describe(self) -> dict[str, Any]:
        d = super().describe()
        d["refine"] = None if self._refine_grid is None else {
            "resolution": resolution_text(self._refine_grid), "radius_deg": self._refine_radius,
            "min_speed_deg_s": self._refine_speed}
        return d

    def _default_resolution(self) -> tuple[int, int]:
        """The catalog's default resolution for ``cross3d`` (its default rule), else 8x16."""
        return catalog.default_resolution(self.model_name) or (8, 16)

    def build_model(self) -> nn.Module:
        from ..cross3d import Cross3D

        return Cross3D(*self._resolution)

    def adapt_weights(self, state: dict[str, torch.Tensor], resolution: tuple[int, int] | None) -> dict[str, torch.Tensor]:
        """Weights for coarser maps widened to this tracker's (:func:`doabench_baselines.cross3d.widen_state`)."""
        from ..cross3d import widen_state

        if resolution is None:
            return super().adapt_weights(state, resolution)
        return widen_state(state, resolution, self._resolution)

    def network_input(self, features: Mapping[str, torch.Tensor]) -> torch.Tensor:
        srp = features["srp"]  # (B, T, n_theta, n_phi)
        if tuple(srp.shape[2:]) != self._resolution:
            raise ConfigError(f"tracker {self.name!r} expects {resolution_text(self._resolution)} maps, "
                              f"got {'x'.join(map(str, srp.shape[2:]))}")
        from ..cross3d import cross3d_input

        x = cross3d_input(srp, features["srp_max"])  # (B, T, 3, n_theta, n_phi)
        return x.transpose(1, 2)
