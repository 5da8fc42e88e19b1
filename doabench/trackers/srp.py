"""Classical trackers on SRP-PHAT maps: ``srp-max`` and ``srp-kalman``."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from doabench.arrays import MicArray
from doabench.errors import ConfigError
from doabench.features.configs import DEFAULT_RESOLUTION
from doabench.features.spec import ObservationSpec
from doabench.geometry import NO_SOURCE, grid_unit_vectors, parse_resolution
from doabench.trackers.base import Tracker
from doabench.trackers.registry import register_tracker

_INITIAL_DIRECTION = np.array([1.0, 0.0, 0.0])  # before the first active frame: straight ahead


class _SrpGridTracker(Tracker):
    observation_spec = ObservationSpec.of(("srp",))
    causal = True
    resolution_in_id = True

    def __init__(self, spec: str | None = None, resolution: str | None = None, **options: Any) -> None:
        super().__init__(spec, **options)
        text = resolution or spec
        self._resolution = parse_resolution(text) if text else DEFAULT_RESOLUTION
        #: its maps on the grid its id names (``srp-max:8x16``)
        self.observation_spec = ObservationSpec.of(("srp",), self._resolution)
        self._grid: np.ndarray | None = None

    def reset(self, array: MicArray, **context: Any) -> None:
        self._grid = grid_unit_vectors(*self._resolution, planar=bool(array.planar)).reshape(-1, 3)

    def _argmax_direction(self, srp: np.ndarray) -> np.ndarray | None:
        """Unit vector of the map's maximum, or None for an all-zero (silent) map."""
        if srp.shape != self._resolution:
            raise ConfigError(f"tracker {self.name!r} expects {self._resolution} maps, got {srp.shape}")
        if not np.any(srp):
            return None
        if self._grid is None:  # what indexing None raised, with the reason
            raise TypeError(f"tracker {self.name!r}: call reset(array) before step()")
        direction: np.ndarray = self._grid[int(np.argmax(srp))]
        return direction


#: what ``srp-max`` reports in a silent frame (its ``silence`` option)
SILENCE_RULES = ("hold", "none")


@register_tracker("srp-max")
class SrpMaxTracker(_SrpGridTracker):
    """Argmax of each SRP-PHAT map (no tracking); holds the last estimate in silent frames.

    Silent frames (the VAD marks them; their maps are zero) carry no information. Option
    ``silence``: ``hold`` (default) repeats the previous estimate (straight ahead before the first
    active frame); ``none`` reports no source (``doabench.NO_SOURCE``) in them, which the LOCATA
    measures count as no active track."""

    def __init__(self, spec: str | None = None, silence: str = "hold", **options: Any) -> None:
        super().__init__(spec, **options)
        if silence not in SILENCE_RULES:
            raise ConfigError(f"srp-max: silence must be one of {', '.join(SILENCE_RULES)}, got {silence!r}")
        self.silence = silence

    def reset(self, array: MicArray, **context: Any) -> None:
        super().reset(array, **context)
        self._last: np.ndarray = _INITIAL_DIRECTION.copy()

    def step(self, observation: Mapping[str, np.ndarray]) -> np.ndarray:
        d = self._argmax_direction(observation["srp"])
        if d is not None:
            self._last = d
        elif self.silence == "none":
            return NO_SOURCE
        return self._last


@register_tracker("srp-kalman")
class SrpKalmanTracker(_SrpGridTracker):
    """SRP argmax followed by a Kalman filter on the unit sphere: the classic two-step tracker.

    State: a 3-D direction with a random-walk model (process noise ``q`` per frame, in squared
    unit-vector units); measurement: the argmax direction with noise ``r``. After each update the
    state is projected back onto the sphere. Silent frames only predict. Measurements further than
    ``gate_deg`` from the prediction are down-weighted (noise times ``gate_factor``), so single
    outlying maxima (reflections) do not pull the track away. Options: ``q``, ``r``, ``gate_deg``,
    ``gate_factor``.
    """

    def __init__(self, spec: str | None = None, q: float = 0.01, r: float = 0.05,
                 gate_deg: float = 45.0, gate_factor: float = 10.0, **options: Any) -> None:
        super().__init__(spec, **options)
        if min(q, r, gate_factor) <= 0:
            raise ConfigError("srp-kalman: q, r and gate_factor must be positive")
        self.q, self.r, self.gate_cos, self.gate_factor = q, r, np.cos(np.radians(gate_deg)), gate_factor

    @property
    def receptive_field_frames(self) -> None:
        return None  # a recursive filter remembers every past frame

    def reset(self, array: MicArray, **context: Any) -> None:
        super().reset(array, **context)
        self._x: np.ndarray = _INITIAL_DIRECTION.copy()
        self._p = 1.0  # isotropic covariance (scalar times identity) keeps the filter in closed form
        self._initialised = False

    def step(self, observation: Mapping[str, np.ndarray]) -> np.ndarray:
        z = self._argmax_direction(observation["srp"])
        self._p += self.q
        if z is not None:
            if not self._initialised:
                self._x, self._p, self._initialised = z.copy(), self.r, True
            else:
                r = self.r if float(z @ self._x) >= self.gate_cos else self.r * self.gate_factor
                gain = self._p / (self._p + r)
                self._x = self._x + gain * (z - self._x)
                self._p = (1 - gain) * self._p
                self._x /= max(np.linalg.norm(self._x), 1e-12)
        return self._x


@register_tracker("srp-kalman-cv")
class SrpKalmanCvTracker(_SrpGridTracker):
    """SRP argmax followed by a constant-velocity Kalman filter on the direction: a tracker that
    models motion (``srp-kalman`` is a random walk and trails a walking talker).

    State ``(u, v)``: the direction ``u`` (a unit vector) and its velocity ``v`` per frame (kept in
    the tangent plane of ``u``), with the nearly-constant-velocity model ``u' = u + v``, ``v' = v``
    and white acceleration noise of spectral density ``q`` (squared unit-vector units per frame^3);
    measurement: the argmax direction with noise ``r``. After each update ``u`` is projected back
    onto the sphere and ``v`` onto its tangent plane. Measurements further than ``gate_deg`` from
    the prediction count with ``gate_factor`` times the noise. In silent frames the filter predicts
    with its velocity shrunk by ``silence_decay`` per frame, so a track coasts briefly through a
    pause and then holds. Options: ``q``, ``r``, ``gate_deg``, ``gate_factor``, ``silence_decay``.
    """

    def __init__(self, spec: str | None = None, q: float = 0.01, r: float = 0.05, gate_deg: float = 45.0,
                 gate_factor: float = 10.0, silence_decay: float = 0.8, **options: Any) -> None:
        super().__init__(spec, **options)
        if min(q, r, gate_factor) <= 0:
            raise ConfigError("srp-kalman-cv: q, r and gate_factor must be positive")
        if not 0 <= silence_decay <= 1:
            raise ConfigError(f"srp-kalman-cv: silence_decay must lie in [0, 1], got {silence_decay}")
        self.q, self.r, self.gate_cos, self.gate_factor = q, r, np.cos(np.radians(gate_deg)), gate_factor
        self.silence_decay = silence_decay
        eye = np.eye(3)
        self._f = np.block([[eye, eye], [np.zeros((3, 3)), eye]])
        # white-acceleration process noise of a unit time step, per axis
        self._qm = q * np.block([[eye / 3.0, eye / 2.0], [eye / 2.0, eye]])

    @property
    def receptive_field_frames(self) -> None:
        return None  # a recursive filter remembers every past frame

    def reset(self, array: MicArray, **context: Any) -> None:
        super().reset(array, **context)
        self._x: np.ndarray = np.concatenate([_INITIAL_DIRECTION, np.zeros(3)])
        self._p = np.eye(6)
        self._initialised = False

    def step(self, observation: Mapping[str, np.ndarray]) -> np.ndarray:
        z = self._argmax_direction(observation["srp"])
        if z is None:
            self._x[3:] *= self.silence_decay
        self._x = self._f @ self._x
        self._p = self._f @ self._p @ self._f.T + self._qm
        if z is not None:
            if not self._initialised:
                self._x = np.concatenate([z, np.zeros(3)])
                self._p = np.diag([self.r] * 3 + [self.q * 10] * 3)
                self._initialised = True
            else:
                u: np.ndarray = self._x[:3] / max(np.linalg.norm(self._x[:3]), 1e-12)
                r = self.r if float(z @ u) >= self.gate_cos else self.r * self.gate_factor
                s = self._p[:3, :3] + r * np.eye(3)
                gain = np.linalg.solve(s, self._p[:3, :]).T  # (6, 3) = P H^T S^-1 (S symmetric)
                self._x = self._x + gain @ (z - self._x[:3])
                self._p = self._p - gain @ self._p[:3, :]
        u = self._x[:3] / max(np.linalg.norm(self._x[:3]), 1e-12)
        self._x[:3] = u
        self._x[3:] -= (self._x[3:] @ u) * u
        direction: np.ndarray = u.copy()
        return direction
