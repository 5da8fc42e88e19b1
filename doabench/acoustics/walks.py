"""Walking talkers and array poses: the scene model beyond the paper's eq. (6) trajectories.

**Walking talker** (:func:`sample_walk`). A person walks at a constant speed ``v`` (m/s) on the
horizontal plane at a fixed mouth height, in *legs* of a few seconds each. A leg is one of

* ``line``: straight on at a random heading;
* ``arc``: around the array at the current horizontal distance (either way round), so the
  direction seen from the array sweeps at ``v / r`` rad/s;
* ``reversal``: turn round (heading + 180 deg) and go on as the previous leg did.

The walker stays inside the room shrunk by ``wall_margin`` and at a horizontal distance from the
array centre inside ``distance``; a step that would leave that region ends the leg early and a
new one starts (up to 16 new legs are tried; if none fits, the walker stands for that step, as a
person does at a wall). A walk that stands for more than a quarter of its steps is redrawn, and
after ``max_tries`` draws the speed range cannot fit the room: ConfigError. The talker keeps
walking through the pauses in their speech. Times: point ``i`` of ``S`` stands for segment ``i``
(:func:`doabench.acoustics.trajectories.segment_bounds`), ``duration / S`` seconds long.

**Array pose.** The array frame is rotated from the room frame by ``R = Rz(yaw) Ry(pitch)
Rx(roll)`` (:func:`rotation_matrix`; a microphone at ``m`` in the array frame is at
``c + R m`` in the room). A moving array (:func:`sample_array_motion`, the NAO head of LOCATA task
5) has one pose per trajectory point: its centre goes back and forth along a horizontal line at
``speed`` m/s within ``travel`` m of its start, its yaw turns at piecewise-constant rates (legs of
1-4 s, each still with probability 1/2 or turning at up to ``yaw_rate`` deg/s) and its pitch nods
sinusoidally (amplitude up to ``pitch_swing`` deg, period 2-8 s).

The generation loops over the ``S`` trajectory points (156 for 20 s): each step depends on the
previous one and on a rejection test, and the whole walk takes about a millisecond.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from doabench.errors import ConfigError
from doabench.geometry import normalize

LEG_KINDS = ("line", "arc", "reversal")
_LEG_P = (0.4, 0.4, 0.2)
_NEW_LEG_TRIES = 16
_MAX_STANDING = 0.25  # a walk standing for more than this fraction of its steps is redrawn
_ROTATION_TOL = 1e-6


def rotation_matrix(yaw_deg, pitch_deg, roll_deg) -> np.ndarray:
    """``Rz(yaw) Ry(pitch) Rx(roll)`` ``(..., 3, 3)`` float64 from angles in degrees (any equal
    leading shapes): the array frame's axes as columns in room coordinates."""
    y, p, r = (np.radians(np.asarray(a, dtype=np.float64)) for a in (yaw_deg, pitch_deg, roll_deg))
    y, p, r = np.broadcast_arrays(y, p, r)
    cy, sy, cp, sp, cr, sr = np.cos(y), np.sin(y), np.cos(p), np.sin(p), np.cos(r), np.sin(r)
    return np.stack([
        np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
        np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
        np.stack([-sp, cp * sr, cp * cr], -1),
    ], -2)


def check_rotations(rotations, what: str = "array rotation") -> np.ndarray:
    """``rotations`` as float64 ``(3, 3)`` or ``(S, 3, 3)``; ConfigError naming ``what`` when one
    is not a proper rotation (orthonormal, determinant +1, within 1e-6)."""
    r = np.asarray(rotations, dtype=np.float64)
    if r.shape[-2:] != (3, 3) or r.ndim not in (2, 3):
        raise ConfigError(f"{what} must have shape (3, 3) or (S, 3, 3), got {r.shape}")
    if not np.all(np.isfinite(r)):
        raise ConfigError(f"{what} holds non-finite values")
    rr = r.reshape(-1, 3, 3)
    ortho = np.abs(np.einsum("sji,sjk->sik", rr, rr) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(rr)
    bad = np.flatnonzero((ortho > _ROTATION_TOL) | (np.abs(det - 1.0) > _ROTATION_TOL))
    if bad.size:
        i = int(bad[0])
        raise ConfigError(f"{what} {i + 1} is not a rotation (R^T R deviates from I by {ortho[i]:.3g}, "
                          f"det {det[i]:.6g})")
    return r


@dataclass(frozen=True)
class WalkDraw:
    """One walking talker: ``points (S, 3)`` room coordinates, its speed (m/s), height (m), the
    kinds of its legs in order, and how many draws it took."""

    points: np.ndarray
    speed: float
    height: float
    legs: tuple[str, ...]
    tries: int

    def params(self) -> dict:
        """JSON-serialisable parameters."""
        return {"family": "walk", "speed": self.speed, "height": self.height, "legs": list(self.legs),
                "tries": self.tries}


def _fits(xy: np.ndarray, new: np.ndarray, lo, hi, centre: np.ndarray, dmin: float, dmax: float) -> bool:
    """A step from ``xy`` to ``new`` stays in the region: its end and its midpoint (a straight
    step past the array could cross the inner circle; an arc's midpoint lies on its circle)."""
    return _inside(new, lo, hi, centre, dmin, dmax) and _inside((xy + new) / 2, lo, hi, centre, 0.9 * dmin, dmax)


def _inside(xy: np.ndarray, lo: np.ndarray, hi: np.ndarray, centre: np.ndarray, dmin: float, dmax: float) -> bool:
    r = math.hypot(xy[0] - centre[0], xy[1] - centre[1])
    return bool(np.all(xy >= lo) and np.all(xy <= hi) and dmin <= r <= dmax)


def _step(xy: np.ndarray, kind: str, heading: float, turn: int, step: float, centre: np.ndarray) -> tuple[np.ndarray, float]:
    """The next horizontal position of a leg and the heading walked."""
    if kind == "arc":
        rel = xy - centre
        r = max(math.hypot(rel[0], rel[1]), 1e-9)
        a = turn * step / r
        c, s = math.cos(a), math.sin(a)
        new = centre + np.array([c * rel[0] - s * rel[1], s * rel[0] + c * rel[1]])
        d = new - xy
        return new, math.atan2(d[1], d[0])
    return xy + step * np.array([math.cos(heading), math.sin(heading)]), heading


def sample_walk(
    rng: np.random.Generator,
    room_dims: np.ndarray,
    array_position: np.ndarray,
    *,
    n_points: int = 156,
    duration_s: float = 20.0,
    speed: tuple[float, float] = (0.3, 1.5),
    distance: tuple[float, float] = (1.0, 4.0),
    height: tuple[float, float] = (1.1, 1.8),
    leg_s: tuple[float, float] = (2.0, 6.0),
    wall_margin: float = 0.1,
    max_tries: int = 200,
    array_path: np.ndarray | None = None,
) -> WalkDraw:
    """Draw a walking talker (module docstring), a pure function of ``rng``'s state.

    ``room_dims`` ``(3,)`` and ``array_position`` ``(3,)`` in metres (the array's start for a
    moving array); ``speed`` m/s, ``distance`` (horizontal, from the array centre) and ``height``
    ranges in metres, ``leg_s`` the range of leg durations in seconds. ``array_path`` ``(S, 3)``:
    a moving array's centres; the distance range then holds from the array where it is at each
    point, and arcs go round it.
    """
    dims = np.asarray(room_dims, dtype=np.float64)
    path = (np.repeat(np.asarray(array_position, np.float64)[None], n_points, 0) if array_path is None
            else np.asarray(array_path, np.float64))[:, :2]
    centre = path[0]
    lo, hi = np.full(2, wall_margin), dims[:2] - wall_margin
    z_hi = dims[2] - wall_margin
    if height[0] > z_hi:
        raise ConfigError(f"walk_height {list(height)} m does not fit under the {dims[2]:g} m ceiling "
                          f"(wall margin {wall_margin} m)")
    dmin, dmax = float(distance[0]), float(distance[1])
    dt = float(duration_s) / n_points
    if speed[1] * dt > dmin / 2:  # one step would jump a good part of the way round the array
        raise ConfigError(f"walk_speed up to {speed[1]:g} m/s moves {speed[1] * dt:.2f} m per trajectory point "
                          f"({dt:.3f} s), more than half the nearest walk_distance {dmin:g} m; lower the speed or use "
                          "more points (n_points)")
    for tries in range(1, max_tries + 1):
        v = float(rng.uniform(*speed))
        z = float(min(rng.uniform(*height), z_hi))
        xy = None
        for _ in range(100):  # a start in the annulus around the array, inside the room
            r, a = rng.uniform(dmin, dmax), rng.uniform(-math.pi, math.pi)
            cand = centre + r * np.array([math.cos(a), math.sin(a)])
            if _inside(cand, lo, hi, centre, dmin, dmax):
                xy = cand
                break
        if xy is None:
            continue
        points = np.empty((n_points, 3))
        points[0] = (*xy, z)
        kind, heading, turn = "line", float(rng.uniform(-math.pi, math.pi)), 1
        left = 0.0
        legs: list[str] = []
        standing = 0
        for i in range(1, n_points):
            if left <= 0:
                kind, heading, turn = _new_leg(rng, kind, heading, turn)
                left = float(rng.uniform(*leg_s))
                legs.append(kind)
            centre = path[i]
            new, walked = _step(xy, kind, heading, turn, v * dt, centre)
            if not _fits(xy, new, lo, hi, centre, dmin, dmax):
                for _ in range(_NEW_LEG_TRIES):
                    kind, heading, turn = _new_leg(rng, kind, heading, turn)
                    new, walked = _step(xy, kind, heading, turn, v * dt, centre)
                    if _fits(xy, new, lo, hi, centre, dmin, dmax):
                        left = float(rng.uniform(*leg_s))
                        legs.append(kind)
                        break
                else:
                    new, walked, left = xy, heading, 0.0
                    standing += 1
            if kind != "arc":
                heading = walked
            xy = new
            points[i] = (*xy, z)
            left -= dt
        if standing <= _MAX_STANDING * n_points:
            return WalkDraw(points, v, z, tuple(legs), tries)
    raise ConfigError(
        f"walk_speed {list(speed)} m/s at walk_distance {list(distance)} m cannot fit a {dims.tolist()} m room "
        f"around an array at {np.round(array_position, 2).tolist()} (no walk in {max_tries} draws)"
    )


def _new_leg(rng: np.random.Generator, kind: str, heading: float, turn: int) -> tuple[str, float, int]:
    new = str(rng.choice(LEG_KINDS, p=_LEG_P))
    h, t = float(rng.uniform(-math.pi, math.pi)), int(rng.choice((-1, 1)))
    if new == "reversal":  # turn round and carry on as before
        return ("arc", heading, -turn) if kind == "arc" else ("line", heading + math.pi, turn)
    return new, h, t


@dataclass(frozen=True)
class ArrayMotion:
    """A moving array's poses: ``centres (S, 3)`` room coordinates and ``rotations (S, 3, 3)``."""

    centres: np.ndarray
    rotations: np.ndarray
    params: dict


def sample_array_motion(
    rng: np.random.Generator,
    room_dims: np.ndarray,
    start: np.ndarray,
    rotation: np.ndarray,
    *,
    n_points: int = 156,
    duration_s: float = 20.0,
    speed: tuple[float, float] = (0.0, 0.2),
    travel: float = 1.0,
    yaw_rate: float = 60.0,
    pitch_swing: float = 15.0,
    radius: float = 0.0,
    wall_margin: float = 0.1,
) -> ArrayMotion:
    """Poses of a moving, turning array (module docstring), a pure function of ``rng``'s state.

    ``start`` ``(3,)`` and ``rotation`` ``(3, 3)``: the pose at the first point; ``radius``: the
    array's radius, kept (with ``wall_margin``) inside the room; the line of travel is shortened
    where the room ends. Vectorised over the ``S`` points.
    """
    dims = np.asarray(room_dims, dtype=np.float64)
    c0 = np.asarray(start, dtype=np.float64)
    t = (np.arange(n_points) + 0.5) * (float(duration_s) / n_points)
    v = float(rng.uniform(*speed))
    a = float(rng.uniform(-math.pi, math.pi))
    direction = np.array([math.cos(a), math.sin(a), 0.0])
    # how far the room lets the centre go along +direction (and -direction) from the start
    lo, hi = np.full(3, wall_margin + radius), dims - wall_margin - radius
    with np.errstate(divide="ignore", invalid="ignore"):
        ahead = np.where(direction > 0, (hi - c0) / direction, np.where(direction < 0, (lo - c0) / direction, np.inf))
    reach = float(max(0.0, min(travel, ahead.min())))
    # back and forth over [0, reach] (a triangle wave), starting at the start
    s = v * t
    offset = reach * (1 - np.abs(1 - 2 * ((s / (2 * reach)) % 1.0))) if reach > 0 else np.zeros_like(t)
    centres = c0 + offset[:, None] * direction
    # yaw: legs of 1-4 s, each still (p = 1/2) or turning at a constant rate
    dt = float(duration_s) / n_points
    n_legs = int(math.ceil(duration_s / 1.0)) + 1
    lengths = rng.uniform(1.0, 4.0, n_legs)
    rates = rng.uniform(-yaw_rate, yaw_rate, n_legs) * (rng.random(n_legs) < 0.5)
    leg_of = np.minimum(np.searchsorted(np.cumsum(lengths), t), n_legs - 1)
    yaw = np.concatenate([[0.0], np.cumsum(rates[leg_of] * dt)[:-1]])
    amp, period, phase = rng.uniform(0, pitch_swing), rng.uniform(2.0, 8.0), rng.uniform(0, 2 * math.pi)
    pitch = amp * (np.sin(2 * math.pi * t / period + phase) - math.sin(2 * math.pi * t[0] / period + phase))
    turns = rotation_matrix(yaw, pitch, np.zeros_like(t))  # relative turn of the head, (S, 3, 3)
    # yaw about the room's vertical and pitch about the array's turned y axis: R_i = Rz Ry applied
    # on the left of the start rotation keeps the head upright where the start is upright
    rotations = np.einsum("sij,jk->sik", turns, np.asarray(rotation, dtype=np.float64))
    params = {"speed": v, "heading": a, "travel": reach, "yaw_rates": rates.tolist(), "leg_s": lengths.tolist(),
              "pitch_amplitude": amp, "pitch_period": period}
    return ArrayMotion(centres, rotations, params)


def array_frame_directions(points: np.ndarray, centres: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """Unit vectors from the array to ``points`` in the array frame, ``(S, 3)`` float64:
    ``R_i^T (p_i - c_i)`` normalised. ``points`` ``(S, 3)`` or ``(1, 3)``, ``centres`` ``(S, 3)``
    or ``(3,)``, ``rotations`` ``(S, 3, 3)`` or ``(3, 3)`` (broadcast over the points)."""
    rel = np.asarray(points, np.float64) - np.asarray(centres, np.float64)
    rot = np.asarray(rotations, np.float64)
    local = np.einsum("...ji,...j->...i", rot, rel) if rot.ndim == 3 else rel @ rot
    return normalize(np.atleast_2d(local))
