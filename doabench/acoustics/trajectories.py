"""Source trajectories (the paper's eq. (6)) and the sample <-> trajectory-point convention.

A trajectory is ``(S, 3)`` points in room coordinates, metres::

    p_i = p_0 + i / (S - 1) * (p_end - p_0) + A * sin(omega * i),   i = 0 .. S - 1

with ``p_0``, ``p_end`` uniform in the room shrunk by ``wall_margin`` on every side, per-axis
``omega`` uniform in ``[0, max_oscillations * 2 pi / S]`` (at most ``max_oscillations`` periods
over the trajectory) and per-axis ``A`` uniform in ``[-b, b]`` where ``b`` is the smaller of
``max_amplitude`` and the distance, along that axis, from the straight line to the shrunk room,
so ``|A sin| <= b`` keeps every point at least ``wall_margin`` from the walls. With probability
``p_static`` the source is static at ``p_0`` (all ``S`` points equal).

**Array clearance rule.** The source must never come closer than ``min_array_distance`` to the
array centre: the whole polyline through the points (not only the points) is checked, and a
trajectory that violates it is redrawn (rejection sampling from the same generator, so the result
is still a pure function of the seed). After ``max_tries`` failures a ConfigError says the room is
too small for that clearance.

**Segment convention** (shared with the simulators): for ``L`` samples and ``S`` points, point ``i``
is where the source is during samples ``[floor(i L / S), floor((i + 1) L / S))``; the simulators
convolve exactly those samples with point ``i``'s RIR (overlap-add), and the per-sample truth uses
the same segments.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from doabench.acoustics.walks import array_frame_directions
from doabench.errors import ConfigError
from doabench.geometry import normalize


def segment_bounds(n_samples: int, n_segments: int) -> np.ndarray:
    """Sample boundaries of the ``S`` segments, ``(S + 1,)`` int64: segment ``i`` is
    ``[b[i], b[i + 1])`` with ``b[i] = floor(i * L / S)`` (lengths differ by at most one sample).
    The simulators' convolution cuts the signal by the same function, so truth and audio can never
    disagree about segments."""
    if n_segments < 1:
        raise ConfigError(f"a trajectory needs at least one point, got {n_segments}")
    return (np.arange(int(n_segments) + 1, dtype=np.int64) * int(n_samples)) // int(n_segments)


def segment_of_samples(n_samples: int, n_segments: int) -> np.ndarray:
    """Index of the trajectory point active at each sample, ``(L,)`` int64."""
    bounds = segment_bounds(n_samples, n_segments)
    return np.repeat(np.arange(n_segments, dtype=np.int64), np.diff(bounds))


def sample_directions(trajectory: np.ndarray, array_position: np.ndarray, n_samples: int,
                      array_rotation: np.ndarray | None = None) -> np.ndarray:
    """Per-sample unit vectors from the array centre to the source in the array frame, ``(L, 3)``
    float64.

    ``trajectory``: ``(S, 3)`` room coordinates; ``array_position``: ``(3,)``, or ``(S, 3)`` for a
    moving array; ``array_rotation``: None (the array axes are the room axes), ``(3, 3)`` or
    ``(S, 3, 3)`` (array frame to room frame, :mod:`doabench.acoustics.walks`). Point ``i`` uses
    pose ``i``; the direction is ``R_i^T (p_i - c_i)`` normalised. A single source point with a
    moving array is heard from every pose.
    """
    traj = np.asarray(trajectory, dtype=np.float64).reshape(-1, 3)
    centres = np.asarray(array_position, dtype=np.float64)
    if array_rotation is None:
        per_point = normalize(traj - centres)
    else:
        per_point = array_frame_directions(traj, centres, array_rotation)
    return per_point[segment_of_samples(n_samples, len(per_point))]


def eq6_points(start: np.ndarray, end: np.ndarray, amplitude: np.ndarray, omega: np.ndarray,
               n_points: int) -> np.ndarray:
    """The paper's eq. (6): straight line plus a per-axis sinusoid, ``(S, 3)``."""
    i = np.arange(n_points, dtype=np.float64)[:, None]
    frac = i / max(n_points - 1, 1)
    return start + frac * (end - start) + amplitude * np.sin(omega * i)


def polyline_distance(points: np.ndarray, target: np.ndarray) -> float:
    """Smallest distance from ``target`` ``(3,)`` to the polyline through ``points`` ``(S, 3)``."""
    p = np.asarray(points, dtype=np.float64)
    if len(p) == 1:
        return float(np.linalg.norm(p[0] - target))
    a, d = p[:-1], np.diff(p, axis=0)
    dd = np.einsum("ij,ij->i", d, d)
    t = np.clip(np.einsum("ij,ij->i", target - a, d) / np.maximum(dd, 1e-300), 0.0, 1.0)
    return float(np.linalg.norm(a + t[:, None] * d - target, axis=1).min())


@dataclass(frozen=True)
class TrajectoryDraw:
    """One drawn trajectory: ``points (S, 3)`` and the eq. (6) parameters that made it."""

    points: np.ndarray
    static: bool
    start: np.ndarray
    end: np.ndarray
    amplitude: np.ndarray
    omega: np.ndarray
    tries: int

    def params(self) -> dict:
        """JSON-serialisable parameters (lists of floats)."""
        return {"start": self.start.tolist(), "end": self.end.tolist(), "amplitude": self.amplitude.tolist(),
                "omega": self.omega.tolist(), "tries": self.tries}


def sample_trajectory(
    rng: np.random.Generator,
    room_dims: np.ndarray,
    array_position: np.ndarray,
    *,
    n_points: int = 156,
    p_static: float = 0.25,
    max_amplitude: float = 1.0,
    max_oscillations: float = 2.0,
    wall_margin: float = 0.1,
    min_array_distance: float = 0.5,
    max_tries: int = 1000,
) -> TrajectoryDraw:
    """Draw a trajectory as described in the module docstring (a pure function of ``rng``'s state).

    ``room_dims``: ``(3,)`` metres; ``array_position``: ``(3,)`` room coordinates of the array centre.
    """
    dims = np.asarray(room_dims, dtype=np.float64)
    centre = np.asarray(array_position, dtype=np.float64)
    lo, hi = np.full(3, wall_margin), dims - wall_margin
    if np.any(hi <= lo):
        raise ConfigError(f"wall margin {wall_margin} m leaves no room for the source in a {dims.tolist()} m room")
    static = bool(rng.random() < p_static)
    omega_max = max_oscillations * 2.0 * math.pi / n_points
    for tries in range(1, max_tries + 1):
        # Always draw every parameter so the number of draws per try does not depend on `static`.
        start = rng.uniform(lo, hi)
        end = rng.uniform(lo, hi)
        bound = np.minimum(np.minimum(np.minimum(start, end) - lo, hi - np.maximum(start, end)), max_amplitude)
        amplitude = rng.uniform(-1.0, 1.0, 3) * np.maximum(bound, 0.0)
        omega = rng.uniform(0.0, 1.0, 3) * omega_max
        if static:
            points = np.repeat(start[None], n_points, axis=0)
        else:
            points = np.clip(eq6_points(start, end, amplitude, omega, n_points), lo, hi)  # clip: rounding only
        if polyline_distance(points, centre) >= min_array_distance:
            return TrajectoryDraw(points, static, start, end, amplitude, omega, tries)
    raise ConfigError(
        f"could not draw a source trajectory keeping {min_array_distance} m from the array in a "
        f"{dims.tolist()} m room after {max_tries} tries; lower min_array_distance or enlarge the room"
    )
