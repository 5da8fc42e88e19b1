"""Shoebox rooms: dimensions, reverberation time and wall absorption.

A :class:`Room` spans ``[0, Lx] x [0, Ly] x [0, Lz]`` metres ("room coordinates"). Walls are
ordered ``x0, x1, y0, y1, z0, z1`` (the wall at ``x = 0``, at ``x = Lx``, ...), which is also the
order of pyroomacoustics' ``west, east, south, north, floor, ceiling``.

The reflection coefficients follow from the T60 by Sabine's formula, as in the Cross3D training
set and gpuRIR::

    T60 = 0.161 V / sum_i S_i alpha_i,    alpha_i = 1 - beta_i**2,    alpha_i = s * w_i

with ``w_i`` the relative absorption weights and ``s`` the one scale that makes the formula hold.
``0.161`` is ``24 ln(10) / c`` at ``c = 343 m/s``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from doabench.errors import ConfigError
from doabench.geometry import SPEED_OF_SOUND

SABINE_CONSTANT = 24.0 * math.log(10.0) / SPEED_OF_SOUND  # 0.1611 s/m
DIFFUSE_START_DB = 12.0  # the ISM runs until the energy has decayed this much (paper / gpuRIR)
MAX_TIME_DB = 40.0  # the RIR ends when the energy has decayed this much
WALL_NAMES = ("x0", "x1", "y0", "y1", "z0", "z1")


def diffuse_start(t60: float) -> float:
    """``Tdiff`` in seconds for a reverberation time ``t60``: the end of the image-source part."""
    return DIFFUSE_START_DB / 60.0 * t60


def max_time(t60: float) -> float:
    """``Tmax`` in seconds for a reverberation time ``t60``: the length of a room impulse response."""
    return MAX_TIME_DB / 60.0 * t60


def _as_floats(value, what: str, n: int) -> tuple[float, ...]:
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ConfigError(f"room {what} must be {n} numbers, got {value!r}") from None
    if arr.size != n:
        raise ConfigError(f"room {what} must be {n} numbers, got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"room {what} contain NaN or infinite values: {value!r}")
    return tuple(float(v) for v in arr)


@dataclass(frozen=True)
class Room:
    """A shoebox room.

    * ``dims``: ``(Lx, Ly, Lz)`` in metres, all > 0.
    * ``t60``: reverberation time in seconds; ``0`` means anechoic (direct path only).
    * ``abs_weights``: relative absorption of the walls ``x0, x1, y0, y1, z0, z1``, each in
      ``(0, 1]`` (the paper draws them uniformly in ``[0.5, 1]``).
    """

    dims: tuple[float, float, float]
    t60: float
    abs_weights: tuple[float, ...] = (1.0,) * 6

    def __post_init__(self) -> None:
        dims = _as_floats(self.dims, "dimensions", 3)
        if min(dims) <= 0:
            raise ConfigError(f"room dimensions must be > 0 metres, got {dims}")
        try:
            t60 = float(self.t60)
        except (TypeError, ValueError):
            raise ConfigError(f"room T60 must be a number of seconds, got {self.t60!r}") from None
        if not math.isfinite(t60) or t60 < 0:
            raise ConfigError(f"room T60 must be finite and >= 0 seconds, got {self.t60!r}")
        weights = _as_floats(self.abs_weights, "absorption weights", 6)
        if min(weights) <= 0 or max(weights) > 1:
            raise ConfigError(f"room absorption weights must each be in (0, 1], got {weights}")
        object.__setattr__(self, "dims", dims)
        object.__setattr__(self, "t60", t60)
        object.__setattr__(self, "abs_weights", weights)
        self.reflection_coefficients()  # an unreachable T60 is a config error right away

    @property
    def volume(self) -> float:
        lx, ly, lz = self.dims
        return lx * ly * lz

    @property
    def wall_areas(self) -> np.ndarray:
        """Areas ``(6,)`` of the walls ``x0, x1, y0, y1, z0, z1`` in square metres."""
        lx, ly, lz = self.dims
        return np.array([ly * lz, ly * lz, lx * lz, lx * lz, lx * ly, lx * ly])

    def min_t60(self) -> float:
        """Shortest T60 Sabine's formula reaches with these weights (the most absorbing wall at
        ``alpha = 1``)."""
        w = np.asarray(self.abs_weights)
        return SABINE_CONSTANT * self.volume * float(w.max()) / float(np.dot(self.wall_areas, w))

    def reflection_coefficients(self) -> np.ndarray:
        """Pressure reflection coefficients ``beta`` ``(6,)`` of walls ``x0 .. z1``, float64.

        All zero for ``t60 == 0``. Raises ConfigError when the T60 is shorter than Sabine's formula
        can give for this room (:meth:`min_t60`).
        """
        if self.t60 == 0:
            return np.zeros(6)
        w = np.asarray(self.abs_weights)
        scale = SABINE_CONSTANT * self.volume / (self.t60 * float(np.dot(self.wall_areas, w)))
        alpha = scale * w
        if alpha.max() > 1.0 + 1e-12:
            raise ConfigError(
                f"T60 = {self.t60:g} s is unreachable in a {self._dims_text()} room with absorption "
                f"weights {self._weights_text()}: Sabine's formula gives at least {self.min_t60():.3f} s"
            )
        return np.sqrt(np.clip(1.0 - alpha, 0.0, 1.0))

    def diffuse_start(self) -> float:
        """``Tdiff`` in seconds: time of a 12 dB energy decay, ``0.2 * T60``."""
        return diffuse_start(self.t60)

    def max_time(self) -> float:
        """``Tmax`` in seconds: time of a 40 dB energy decay, ``(40 / 60) * T60``."""
        return max_time(self.t60)

    def contains(self, points) -> np.ndarray:
        """Points ``(..., 3)`` in room coordinates -> bool ``(...)``, True strictly inside
        (points on a wall would coincide with their own image)."""
        p = np.asarray(points, dtype=np.float64)
        if p.shape[-1:] != (3,):
            raise ConfigError(f"points must have shape (..., 3), got {p.shape}")
        dims = np.asarray(self.dims)
        with np.errstate(invalid="ignore"):
            return np.all((p > 0) & (p < dims), axis=-1)

    def to_dict(self) -> dict:
        return {"dims": list(self.dims), "t60": self.t60, "abs_weights": list(self.abs_weights)}

    def _dims_text(self) -> str:
        return "x".join(f"{d:g}" for d in self.dims) + " m"

    def _weights_text(self) -> str:
        return "(" + ", ".join(f"{w:.3g}" for w in self.abs_weights) + ")"


def check_inside(room: Room, points, what: str) -> np.ndarray:
    """Validate points ``(N, 3)`` (or one ``(3,)``) against ``room``; return them as float64.

    Raises ConfigError naming the first bad one as ``"{what} {i}"`` (1-based), e.g.
    ``check_inside(room, mics, "array microphone")`` -> "array microphone 3 at (...) is outside
    the 4x5x3 m room". A single point is named just ``what``.
    """
    p = np.asarray(points, dtype=np.float64)
    single = p.ndim == 1
    if single:
        p = p[None]
    if p.ndim != 2 or p.shape[1] != 3:
        raise ConfigError(f"{what} positions must have shape (N, 3), got {np.shape(points)}")
    bad_value = ~np.all(np.isfinite(p), axis=1)
    outside = ~room.contains(p)
    for bad, problem in ((bad_value, "is not finite"), (outside, f"is outside the {room._dims_text()} room")):
        if bad.any():
            i = int(np.argmax(bad))
            name = what if single else f"{what} {i + 1}"
            xyz = ", ".join(f"{v:.3g}" for v in p[i])
            raise ConfigError(f"{name} at ({xyz}) {problem}")
    return p[0] if single else p
