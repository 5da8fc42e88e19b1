"""Random acoustic scenes (the paper's section IV-A) as a pure function of (distribution, seed).

:class:`SceneDistribution` holds every range and probability (defaults: the paper's values);
:func:`sample_scene` draws a :class:`Scene` from it. Randomness comes from
``numpy.random.SeedSequence(seed).spawn(...)``, one independent stream per part (see ``STREAMS``):
fixing T60 or changing the trajectory rules does not move the array, the speech chunk or the noise
of the same seed. Degenerate ranges such as ``t60 = (0.9, 0.9)`` still consume their draw for the
same reason.

Distributions load from and dump to plain dicts (the ``[scene]`` table of a task TOML file); a
range key also accepts a single number (``t60 = 0.9`` is ``t60 = [0.9, 0.9]``).
"""
from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Sequence, cast

import numpy as np

from doabench.acoustics.room import Room, check_inside
from doabench.acoustics.trajectories import sample_directions, sample_trajectory, segment_bounds
from doabench.acoustics.walks import check_rotations, rotation_matrix, sample_array_motion, sample_walk
from doabench.arrays import MicArray, get_array
from doabench.errors import ConfigError
from doabench.geometry import angular_speed_deg

# Independent random streams of a scene seed, in SeedSequence spawn order. Append, never reorder:
# the order is part of what makes a seed reproduce the same scene.
STREAMS = ("room", "array", "trajectory", "speech", "noise", "simulator", "directional", "directional_signal",
           "pauses", "walk", "array_pose")
NOISE_KINDS = ("pink", "brown", "lowpass")


def scene_streams(seed: int) -> dict[str, np.random.SeedSequence]:
    """The named child SeedSequences of a scene seed (``STREAMS``)."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"scene seed must be a non-negative integer, got {seed!r}")
    return dict(zip(STREAMS, np.random.SeedSequence(int(seed)).spawn(len(STREAMS))))


def stream_rng(seed: int, name: str) -> np.random.Generator:
    """``numpy.random.default_rng`` on the named stream of a scene seed."""
    return np.random.default_rng(scene_streams(seed)[name])


Range = tuple[float, float]
Vec3 = tuple[float, float, float]

# Field groups for validation and dict conversion.
_RANGES = ("t60", "snr", "abs_weights", "directional_noise_snr", "pause_s", "pause_count", "walk_speed",
           "walk_distance", "walk_height", "walk_leg_s", "array_yaw", "array_pitch", "array_roll", "array_speed")
# Fields beyond the paper that a distribution's dict names only when they differ from these
# defaults, so the dicts (and results) of the tasks that predate them stay as they were.
_OPTIONAL_DEFAULTS: dict[str, Any] = {
    "pause_after_s": 0.0, "pause_hold": False, "walk_p": 0.0, "walk_speed": [0.3, 1.5],
    "walk_distance": [1.0, 4.0], "walk_height": [1.1, 1.8], "walk_leg_s": [2.0, 6.0], "array_yaw": [0.0, 0.0],
    "array_pitch": [0.0, 0.0], "array_roll": [0.0, 0.0], "array_turn_p": 1.0, "array_motion_p": 0.0, "array_speed": [0.0, 0.2],
    "array_travel": 1.0, "array_yaw_rate": 60.0, "array_pitch_swing": 15.0,
}
_VEC3 = ("room_min", "room_max", "array_fraction_min", "array_fraction_max")


@dataclass(frozen=True)
class SceneDistribution:
    """Every range and probability of the scene generator; defaults are the paper's.

    Lengths in metres, T60 in seconds, SNRs in dB. ``array_fraction_*`` place the array centre as
    fractions of the room dimensions. ``directional_noise_p`` is the probability that a scene adds
    a stationary directional noise source (e.g. a fan; off by default) of kind
    ``directional_noise_kind`` at a random position, ``directional_noise_snr`` dB below the speech
    at the microphones (reverberant speech over non-silent frames vs. reverberant noise).
    """

    room_min: Vec3 = (3.0, 3.0, 2.5)
    room_max: Vec3 = (10.0, 8.0, 6.0)
    t60: Range = (0.2, 1.3)
    snr: Range = (5.0, 30.0)
    abs_weights: Range = (0.5, 1.0)
    array_fraction_min: Vec3 = (0.1, 0.1, 0.1)
    array_fraction_max: Vec3 = (0.9, 0.9, 0.5)
    n_points: int = 156
    duration_s: float = 20.0
    p_static: float = 0.25
    max_amplitude: float = 1.0
    max_oscillations: float = 2.0
    wall_margin: float = 0.1
    min_array_distance: float = 0.5
    fs: int = 16000
    directional_noise_p: float = 0.0
    directional_noise_snr: Range = (10.0, 30.0)
    directional_noise_kind: str = "pink"
    # Beyond the paper: with probability pause_p a scene silences its talker for pause_count
    # (inclusive integer range) intervals of pause_s seconds each, so a tracker must hold its
    # track through long silences (LOCATA has pauses of several seconds).
    pause_p: float = 0.0
    pause_count: Range = (1.0, 2.0)
    pause_s: Range = (2.0, 5.0)
    # pause_after_s: pauses start no earlier (so a tracker has heard the talker before one);
    # pause_hold: the talker stands still while silent (its path resumes where it stopped), so a
    # tracker that holds its track is right; otherwise it walks on through the pause.
    pause_after_s: float = 0.0
    pause_hold: bool = False
    # Beyond the paper, moving talkers (doabench.acoustics.walks): with probability walk_p the
    # talker is a person walking at walk_speed m/s (constant per scene) in lines, arcs around the
    # array and reversals, walk_distance m (horizontally) from the array, mouth at walk_height m,
    # in legs of walk_leg_s seconds; a walker keeps walking through pauses (pause_hold is for the
    # paper's trajectories).
    walk_p: float = 0.0
    walk_speed: Range = (0.3, 1.5)
    walk_distance: Range = (1.0, 4.0)
    walk_height: Range = (1.1, 1.8)
    walk_leg_s: Range = (2.0, 6.0)
    # The array's orientation: with probability array_turn_p, yaw, pitch and roll in degrees,
    # uniform in these ranges (0 or otherwise: the array axes are the room axes, as in the
    # paper). With probability array_motion_p the array
    # moves and turns like a robot head: back and forth at array_speed m/s within array_travel m,
    # yaw turning at up to array_yaw_rate deg/s, pitch nodding up to array_pitch_swing deg.
    array_yaw: Range = (0.0, 0.0)
    array_pitch: Range = (0.0, 0.0)
    array_roll: Range = (0.0, 0.0)
    array_turn_p: float = 1.0
    array_motion_p: float = 0.0
    array_speed: Range = (0.0, 0.2)
    array_travel: float = 1.0
    array_yaw_rate: float = 60.0
    array_pitch_swing: float = 15.0

    def __post_init__(self) -> None:
        for name in _RANGES + _VEC3:
            value = getattr(self, name)
            n = 2 if name in _RANGES else 3
            try:
                tup = tuple(float(v) for v in value)
            except (TypeError, ValueError):
                raise ConfigError(f"scene parameter {name} must be a list of {n} numbers, got {value!r}") from None
            if len(tup) != n or not all(math.isfinite(v) for v in tup):
                raise ConfigError(f"scene parameter {name} must be {n} finite numbers, got {list(tup)}")
            object.__setattr__(self, name, tup)
        for name in _RANGES:
            lo, hi = getattr(self, name)
            if lo > hi:
                raise ConfigError(f"scene parameter {name}: low {lo} is above high {hi}")
        _check(self.t60[0] >= 0, f"t60 must be >= 0 s (0 = anechoic), got {list(self.t60)}")
        _check(0 <= self.abs_weights[0] and self.abs_weights[1] <= 1 and self.abs_weights[1] > 0,
               f"abs_weights must lie in [0, 1] with a positive high value, got {list(self.abs_weights)}")
        _check(all(0 < a <= b for a, b in zip(self.room_min, self.room_max)),
               f"room_min {list(self.room_min)} must be positive and not above room_max {list(self.room_max)}")
        _check(all(0 <= a <= b <= 1 for a, b in zip(self.array_fraction_min, self.array_fraction_max)),
               "array_fraction_min/max must be fractions in [0, 1] with min <= max, got "
               f"{list(self.array_fraction_min)} / {list(self.array_fraction_max)}")
        for name in ("n_points", "fs"):
            v = getattr(self, name)
            _check(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 1,
                   f"scene parameter {name} must be a positive integer, got {v!r}")
            object.__setattr__(self, name, int(v))
        for name in ("duration_s", "p_static", "max_amplitude", "max_oscillations", "wall_margin",
                     "min_array_distance", "directional_noise_p", "pause_p", "pause_after_s", "walk_p",
                     "array_turn_p", "array_motion_p", "array_travel", "array_yaw_rate", "array_pitch_swing"):
            v = getattr(self, name)
            _check(isinstance(v, (int, float, np.number)) and not isinstance(v, bool) and math.isfinite(v),
                   f"scene parameter {name} must be a finite number, got {v!r}")
            object.__setattr__(self, name, float(v))
        _check(self.duration_s > 0, f"duration_s must be positive, got {self.duration_s}")
        _check(0 <= self.p_static <= 1, f"p_static must be a probability in [0, 1], got {self.p_static}")
        _check(0 <= self.directional_noise_p <= 1,
               f"directional_noise_p must be a probability in [0, 1], got {self.directional_noise_p}")
        _check(self.max_amplitude >= 0 and self.max_oscillations >= 0 and self.min_array_distance >= 0,
               "max_amplitude, max_oscillations and min_array_distance must be >= 0")
        _check(0 <= 2 * self.wall_margin < min(self.room_min),
               f"wall_margin {self.wall_margin} m must be >= 0 and leave room in the smallest room {list(self.room_min)}")
        _check(self.directional_noise_kind in NOISE_KINDS,
               f"directional_noise_kind must be one of {', '.join(NOISE_KINDS)}, got {self.directional_noise_kind!r}")
        _check(0 <= self.pause_p <= 1, f"pause_p must be a probability in [0, 1], got {self.pause_p}")
        _check(self.pause_count[0] >= 0 and all(float(c).is_integer() for c in self.pause_count),
               f"pause_count must be two non-negative integers, got {list(self.pause_count)}")
        _check(self.pause_s[0] >= 0, f"pause_s must be >= 0 s, got {list(self.pause_s)}")
        _check(self.pause_after_s >= 0, f"pause_after_s must be >= 0 s, got {self.pause_after_s}")
        _check(isinstance(self.pause_hold, (bool, np.bool_)), f"pause_hold must be true or false, got {self.pause_hold!r}")
        object.__setattr__(self, "pause_hold", bool(self.pause_hold))
        for name in ("walk_p", "array_turn_p", "array_motion_p"):
            _check(0 <= getattr(self, name) <= 1, f"{name} must be a probability in [0, 1], got {getattr(self, name)}")
        _check(self.walk_speed[0] > 0, f"walk_speed must be positive m/s, got {list(self.walk_speed)}")
        _check(self.walk_distance[0] > 0, f"walk_distance must be positive metres, got {list(self.walk_distance)}")
        _check(self.walk_height[0] > 0, f"walk_height must be positive metres, got {list(self.walk_height)}")
        _check(self.walk_leg_s[0] > 0, f"walk_leg_s must be positive seconds, got {list(self.walk_leg_s)}")
        _check(self.walk_p == 0 or self.walk_height[0] < self.room_max[2] - self.wall_margin,
               f"walk_height {list(self.walk_height)} m does not fit under the highest ceiling {self.room_max[2]} m")
        _check(self.walk_p == 0 or self.walk_distance[0] < max(self.room_max[:2]) - 2 * self.wall_margin,
               f"walk_distance {list(self.walk_distance)} m cannot fit rooms of at most {list(self.room_max)} m")
        for name, bound in (("array_yaw", 180.0), ("array_pitch", 90.0), ("array_roll", 180.0)):
            _check(-bound <= getattr(self, name)[0] and getattr(self, name)[1] <= bound,
                   f"{name} must lie in [-{bound:g}, {bound:g}] degrees, got {list(getattr(self, name))}")
        _check(self.array_speed[0] >= 0 and self.array_travel >= 0 and self.array_yaw_rate >= 0
               and self.array_pitch_swing >= 0,
               "array_speed, array_travel, array_yaw_rate and array_pitch_swing must be >= 0")

    @property
    def n_samples(self) -> int:
        return int(round(self.duration_s * self.fs))

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (lists, numbers, strings) that :meth:`from_dict` reads back. The later pause
        options appear only when set, so the distributions of earlier tasks keep their dicts."""
        d = {f.name: (list(v) if isinstance(v := getattr(self, f.name), tuple) else v)
             for f in dataclasses.fields(self)}
        for name, default in _OPTIONAL_DEFAULTS.items():
            if d[name] == default:
                del d[name]
        return d

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> "SceneDistribution":
        """Build from a (partial) dict; missing keys keep the paper's defaults."""
        data = dict(data or {})
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(f"unknown scene parameter(s) {', '.join(unknown)} (known: {', '.join(sorted(known))})")
        for name in _RANGES:
            if name in data and isinstance(data[name], (int, float)) and not isinstance(data[name], bool):
                data[name] = (data[name], data[name])
        return cls(**data)

    def replace(self, **changes: Any) -> "SceneDistribution":
        return dataclasses.replace(self, **changes)


def _check(ok: bool | np.bool_, message: str) -> None:
    if not ok:
        raise ConfigError(message)


@dataclass(frozen=True)
class DirectionalNoise:
    """A static, stationary noise source: ``position`` ``(3,)`` room coordinates, its level
    ``snr_db`` below the speech, and its spectrum ``kind`` (pink, brown or lowpass)."""

    position: np.ndarray
    snr_db: float
    kind: str = "pink"

    def __post_init__(self) -> None:
        pos = np.asarray(self.position, dtype=np.float64).reshape(3)
        pos.setflags(write=False)
        object.__setattr__(self, "position", pos)
        _check(math.isfinite(self.snr_db), f"directional noise SNR must be finite, got {self.snr_db}")
        _check(self.kind in NOISE_KINDS, f"directional noise kind must be one of {', '.join(NOISE_KINDS)}")

    def to_dict(self) -> dict[str, Any]:
        return {"position": self.position.tolist(), "snr_db": float(self.snr_db), "kind": self.kind}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "DirectionalNoise":
        return cls(np.asarray(d["position"], dtype=np.float64), float(d["snr_db"]), str(d.get("kind", "pink")))


def _frozen_array(x, shape_last: int = 3) -> np.ndarray:
    a = np.array(x, dtype=np.float64)
    if a.ndim == 1:
        a = a.reshape(-1, shape_last) if a.size != shape_last else a
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Scene:
    """One drawn scene. Positions in metres in room coordinates unless said otherwise.

    * ``array_position``: ``(3,)`` array centre (at the first point for a moving array);
      ``mic_positions``: ``(M, 3)`` in the array frame
    * ``array_rotation``: None (the array axes are the room axes), ``(3, 3)`` (a turned array) or
      ``(S, 3, 3)`` (one per trajectory point: a turning array), array frame to room frame
    * ``array_path``: None (a static array) or ``(S, 3)`` array centres per trajectory point
    * ``trajectory``: ``(S, 3)`` source positions, point ``i`` active during segment ``i``
      (see :mod:`doabench.acoustics.trajectories`); all equal when ``static``
    * ``speech``: the speech source's chunk ``info`` (None for geometry-only scenes)
    * ``seed``: the scene seed; noise and simulator randomness come from its streams
    """

    room: Room
    snr_db: float
    array_position: np.ndarray
    array_name: str
    mic_positions: np.ndarray
    trajectory: np.ndarray
    static: bool
    seed: int
    duration_s: float
    fs: int = 16000
    speech: dict[str, Any] | None = None
    directional_noise: DirectionalNoise | None = None
    trajectory_params: dict[str, Any] = field(default_factory=dict)
    #: ``[start, stop)`` sample intervals in which the talker is silent (beyond the paper)
    speech_pauses: tuple[tuple[int, int], ...] = ()
    array_rotation: np.ndarray | None = None
    array_path: np.ndarray | None = None
    array_motion_params: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "array_position", _frozen_array(self.array_position).reshape(3))
        object.__setattr__(self, "mic_positions", _frozen_array(self.mic_positions))
        traj = _frozen_array(self.trajectory)
        object.__setattr__(self, "trajectory", traj)
        _check(traj.ndim == 2 and traj.shape[1] == 3 and len(traj) >= 1,
               f"trajectory must have shape (S, 3), got {traj.shape}")
        _check(self.mic_positions.ndim == 2 and self.mic_positions.shape[1] == 3,
               f"mic_positions must have shape (M, 3), got {self.mic_positions.shape}")
        _check(isinstance(self.snr_db, (int, float, np.number)) and math.isfinite(self.snr_db),
               f"scene SNR must be a finite number of dB, got {self.snr_db!r}")
        _check(math.isfinite(self.room.t60) and self.room.t60 >= 0,
               f"scene T60 must be >= 0 s (0 = anechoic), got {self.room.t60}")
        _check(math.isfinite(self.duration_s) and self.duration_s > 0,
               f"scene duration must be positive, got {self.duration_s}")
        _check(int(self.fs) > 0, f"scene sample rate must be positive, got {self.fs}")
        if self.static:
            _check(bool(np.all(traj == traj[0])), "a static scene's trajectory points must all be equal")
        object.__setattr__(self, "snr_db", float(self.snr_db))
        object.__setattr__(self, "speech", copy.deepcopy(self.speech))  # not shared with the caller
        object.__setattr__(self, "trajectory_params", copy.deepcopy(dict(self.trajectory_params)))
        object.__setattr__(self, "fs", int(self.fs))
        pauses = tuple((int(a), int(b)) for a, b in self.speech_pauses)
        _check(all(0 <= a <= b <= self.n_samples for a, b in pauses),
               f"speech pauses must be sample intervals inside the scene, got {[list(p) for p in pauses]}")
        object.__setattr__(self, "speech_pauses", pauses)
        if self.array_rotation is not None:
            rot = check_rotations(self.array_rotation)
            _check(rot.ndim == 2 or len(rot) == len(traj),
                   f"array_rotation must be (3, 3) or one per trajectory point ({len(traj)}), got {rot.shape}")
            rot = rot.copy()
            rot.setflags(write=False)
            object.__setattr__(self, "array_rotation", rot)
        if self.array_path is not None:
            path = _frozen_array(self.array_path)
            _check(path.ndim == 2 and path.shape == (len(traj), 3),
                   f"array_path must have shape ({len(traj)}, 3), one centre per trajectory point, got {path.shape}")
            object.__setattr__(self, "array_path", path)
            check_inside(self.room, path, "array centre")
        object.__setattr__(self, "array_motion_params", copy.deepcopy(dict(self.array_motion_params)))
        check_inside(self.room, self.array_position[None], "array centre")
        check_inside(self.room, self.mic_room_positions.reshape(-1, 3), "microphone")
        check_inside(self.room, traj, "source")
        if self.directional_noise is not None:
            check_inside(self.room, self.directional_noise.position[None], "directional noise source")

    # -- derived quantities

    @property
    def n_samples(self) -> int:
        return int(round(self.duration_s * self.fs))

    @property
    def moving_array(self) -> bool:
        """True when the array has a pose per trajectory point (it moves or turns)."""
        return self.array_path is not None or (self.array_rotation is not None and self.array_rotation.ndim == 3)

    @property
    def array_centres(self) -> np.ndarray:
        """Array centre per trajectory point ``(S, 3)`` for a moving array, else ``(3,)``."""
        if self.moving_array:
            if self.array_path is not None:
                return self.array_path
            return np.repeat(self.array_position[None], len(self.trajectory), axis=0)
        return self.array_position

    @property
    def mic_room_positions(self) -> np.ndarray:
        """Microphones in room coordinates: ``(M, 3)``, or ``(S, M, 3)`` for a moving array (the
        microphones at each trajectory point's pose: ``c_i + R_i m``)."""
        rot = self.array_rotation
        local = self.mic_positions if rot is None else np.einsum("...ij,mj->...mi", rot, self.mic_positions)
        centres = self.array_centres
        return (centres[:, None, :] if centres.ndim == 2 else centres) + local

    @property
    def source_positions(self) -> np.ndarray:
        """What the simulator gets: ``(1, 3)`` for a static source, else the trajectory ``(S, 3)``."""
        return self.trajectory[:1] if self.static else self.trajectory

    @property
    def speed_deg_s(self) -> np.ndarray:
        """Angular speed of the source seen from the array, deg/s per trajectory point ``(S,)``."""
        dirs = sample_directions(self.trajectory, self.array_centres, len(self.trajectory), self.array_rotation)
        times = (np.arange(len(dirs)) + 0.5) * (self.duration_s / len(dirs))
        return angular_speed_deg(dirs, times)

    @property
    def array(self) -> MicArray:
        return MicArray(self.array_name, np.array(self.mic_positions), source="scene")

    def sample_directions(self, n_samples: int | None = None) -> np.ndarray:
        """Per-sample truth directions in the array frame, ``(L, 3)`` float64 unit vectors."""
        n = self.n_samples if n_samples is None else n_samples
        if self.moving_array:
            return sample_directions(self.trajectory, self.array_centres, n, self.array_rotation)
        return sample_directions(self.source_positions, self.array_position, n, self.array_rotation)

    # -- serialisation

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable description; :meth:`from_dict` rebuilds an equal scene."""
        return {
            "room": {"dims": [float(d) for d in self.room.dims], "t60": float(self.room.t60),
                     "abs_weights": [float(w) for w in self.room.abs_weights]},  # = Room.to_dict()
            "snr_db": self.snr_db,
            "array": {"name": self.array_name, "position": self.array_position.tolist(),
                      "mic_positions": self.mic_positions.tolist()},
            "trajectory": self.trajectory.tolist(),
            "static": bool(self.static),
            "seed": int(self.seed),
            "duration_s": float(self.duration_s),
            "fs": self.fs,
            "speech": copy.deepcopy(self.speech),  # fresh objects: callers may mutate the dict
            "directional_noise": None if self.directional_noise is None else self.directional_noise.to_dict(),
            "trajectory_params": copy.deepcopy(self.trajectory_params),
            # only when present, so scenes without pauses keep their description
            **({"speech_pauses": [list(p) for p in self.speech_pauses]} if self.speech_pauses else {}),
            **({"array_rotation": self.array_rotation.tolist()} if self.array_rotation is not None else {}),
            **({"array_path": self.array_path.tolist()} if self.array_path is not None else {}),
            **({"array_motion_params": copy.deepcopy(self.array_motion_params)} if self.array_motion_params else {}),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Scene":
        try:
            # Room checks that there are three
            dims = cast(tuple[float, float, float], tuple(float(x) for x in d["room"]["dims"]))
            room = Room(dims, float(d["room"]["t60"]), tuple(float(w) for w in d["room"]["abs_weights"]))
            noise = d.get("directional_noise")
            return cls(
                room=room, snr_db=float(d["snr_db"]),
                array_position=np.asarray(d["array"]["position"], dtype=np.float64),
                array_name=str(d["array"]["name"]),
                mic_positions=np.asarray(d["array"]["mic_positions"], dtype=np.float64),
                trajectory=np.asarray(d["trajectory"], dtype=np.float64),
                static=bool(d["static"]), seed=int(d["seed"]), duration_s=float(d["duration_s"]),
                fs=int(d.get("fs", 16000)), speech=d.get("speech"),
                directional_noise=None if noise is None else DirectionalNoise.from_dict(noise),
                trajectory_params=dict(d.get("trajectory_params", {})),
                speech_pauses=tuple(tuple(p) for p in d.get("speech_pauses", ())),
                array_rotation=None if d.get("array_rotation") is None else np.asarray(d["array_rotation"], np.float64),
                array_path=None if d.get("array_path") is None else np.asarray(d["array_path"], np.float64),
                array_motion_params=dict(d.get("array_motion_params", {})),
            )
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, ConfigError):
                raise
            raise ConfigError(f"invalid scene description ({type(exc).__name__}: {exc})") from None

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Scene) and self.to_dict() == other.to_dict()

    # mutable-looking contents (dicts); scenes are compared, not hashed. None is how Python marks a class
    # unhashable, which typeshed's Callable type of object.__hash__ does not allow for.
    __hash__ = None  # type: ignore[assignment]


MAX_ROOM_TRIES = 1000


def _sample_room(r: np.random.Generator, dist: SceneDistribution) -> tuple[Room, float]:
    """T60 and SNR first, then room size and wall weights, redrawn until Sabine's formula can
    reach the T60 (small T60 in big rooms can need an absorption above 1). Redrawing the room
    rather than the T60 keeps the T60 distribution exact (grid cells fix it), at the price of
    slightly favouring smaller rooms at the lowest T60s (about 15 % of the paper's rooms cannot
    reach 0.2 s; every room reaches 0.3 s)."""
    t60 = float(r.uniform(*dist.t60))
    snr = float(r.uniform(*dist.snr))
    low = max(dist.abs_weights[0], 1e-6)  # Room needs weights > 0
    for _ in range(MAX_ROOM_TRIES):
        # three: room_min and room_max are (x, y, z) bounds
        dims = cast(tuple[float, float, float], tuple(float(x) for x in r.uniform(dist.room_min, dist.room_max)))
        weights = tuple(float(w) for w in r.uniform(low, dist.abs_weights[1], 6))
        if t60 == 0 or Room(dims, 0.0, weights).min_t60() <= t60:
            return Room(dims, t60, weights), snr
    raise ConfigError(f"T60 = {t60:g} s is unreachable (Sabine) for rooms between {list(dist.room_min)} and "
                      f"{list(dist.room_max)} m with absorption weights {list(dist.abs_weights)}")


def sample_scene(
    dist: SceneDistribution,
    seed: int,
    speech_source=None,
    array: MicArray | str = "nao",
) -> Scene:
    """Draw the scene of ``seed`` from ``dist`` (a pure function of both).

    ``speech_source``: a :class:`~doabench.corpora.speech.SpeechSource` whose chunk ``info`` the
    scene records (None: geometry only, the scene cannot be rendered). ``array``: the microphone
    array (its positions are recorded in the scene).
    """
    if not isinstance(dist, SceneDistribution):
        raise ConfigError(f"sample_scene needs a SceneDistribution, got {type(dist).__name__}")
    array = get_array(array)
    rngs = {name: np.random.default_rng(ss) for name, ss in scene_streams(seed).items()}

    room, snr = _sample_room(rngs["room"], dist)
    dims = np.asarray(room.dims)

    centre = dims * rngs["array"].uniform(dist.array_fraction_min, dist.array_fraction_max)

    draw = sample_trajectory(
        rngs["trajectory"], dims, centre, n_points=dist.n_points, p_static=dist.p_static,
        max_amplitude=dist.max_amplitude, max_oscillations=dist.max_oscillations,
        wall_margin=dist.wall_margin, min_array_distance=dist.min_array_distance,
    )

    speech = None
    if speech_source is not None:
        speech = speech_source.sample(rngs["speech"], dist.duration_s, dist.fs).info

    noise = None
    d = rngs["directional"]
    enabled = d.random() < dist.directional_noise_p
    # The noise position obeys the same wall margin and array clearance as a static talker.
    noise_draw = sample_trajectory(d, dims, centre, n_points=1, p_static=1.0, wall_margin=dist.wall_margin,
                                   min_array_distance=dist.min_array_distance)
    noise_snr = float(d.uniform(*dist.directional_noise_snr))
    if enabled:
        noise = DirectionalNoise(noise_draw.points[0], noise_snr, dist.directional_noise_kind)

    pauses = sample_pauses(rngs["pauses"], dist)
    points, static, params = draw.points, draw.static, draw.params()
    rotation, path, motion = _sample_array_pose(rngs["array_pose"], dist, dims, centre, array)
    walk = _sample_walk(rngs["walk"], dist, dims, centre, path)
    if walk is not None:
        points, static, params = walk.points, False, walk.params()
    elif dist.pause_hold and pauses and not draw.static:
        points = hold_during_pauses(points, pauses, dist.n_samples)
    if path is not None and static:  # a moving array hears a static talker from every pose
        points = np.repeat(points[:1], dist.n_points, axis=0)
    if path is not None and walk is None:  # the paper's trajectories: keep them clear of the moving array
        _check_clearance(points, path, dist.min_array_distance)
    return Scene(
        room=room, snr_db=snr, array_position=centre, array_name=array.name,
        mic_positions=np.array(array.positions), trajectory=points, static=static,
        seed=int(seed), duration_s=dist.duration_s, fs=dist.fs, speech=speech,
        directional_noise=noise, trajectory_params=params,
        speech_pauses=pauses, array_rotation=rotation, array_path=path, array_motion_params=motion,
    )


def _sample_walk(r: np.random.Generator, dist: SceneDistribution, dims: np.ndarray, centre: np.ndarray,
                 array_path: np.ndarray | None):
    """A walking talker with probability ``walk_p`` (its own stream: other parts do not move)."""
    if dist.walk_p == 0 or not r.random() < dist.walk_p:
        return None
    return sample_walk(r, dims, centre, n_points=dist.n_points, duration_s=dist.duration_s, speed=dist.walk_speed,
                       distance=dist.walk_distance, height=dist.walk_height, leg_s=dist.walk_leg_s,
                       wall_margin=dist.wall_margin, array_path=array_path)


def _sample_array_pose(r: np.random.Generator, dist: SceneDistribution, dims: np.ndarray, centre: np.ndarray,
                       array: MicArray):
    """``(rotation, path, motion params)``: None, None, {} for the paper's axis-aligned static array."""
    ranges = (dist.array_yaw, dist.array_pitch, dist.array_roll)
    turned = any(lo != 0 or hi != 0 for lo, hi in ranges) and r.random() < dist.array_turn_p
    moving = dist.array_motion_p > 0 and r.random() < dist.array_motion_p
    if not turned and not moving:
        return None, None, {}
    yaw, pitch, roll = (float(r.uniform(lo, hi)) if turned else 0.0 for lo, hi in ranges)
    rotation = rotation_matrix(yaw, pitch, roll)
    if not moving:
        return rotation, None, {}
    radius = float(np.linalg.norm(array.positions, axis=1).max())
    motion = sample_array_motion(r, dims, centre, rotation, n_points=dist.n_points, duration_s=dist.duration_s,
                                 speed=dist.array_speed, travel=dist.array_travel, yaw_rate=dist.array_yaw_rate,
                                 pitch_swing=dist.array_pitch_swing, radius=radius, wall_margin=dist.wall_margin)
    return motion.rotations, motion.centres, motion.params


def _check_clearance(points: np.ndarray, centres: np.ndarray, min_distance: float) -> None:
    d = np.linalg.norm(points - centres, axis=1)
    if d.min() < min_distance:
        raise ConfigError(f"the moving array comes within {d.min():.2f} m of the talker (min_array_distance "
                          f"{min_distance} m); the scene is rejected")


def sample_pauses(rng: np.random.Generator, dist: SceneDistribution) -> tuple[tuple[int, int], ...]:
    """The speech pauses of a scene (see ``SceneDistribution.pause_p``): sorted sample intervals,
    each of a length uniform in ``pause_s``, placed uniformly in the scene (they may overlap)."""
    if dist.pause_p == 0 or not rng.random() < dist.pause_p:
        return ()
    n = dist.n_samples
    count = int(rng.integers(int(dist.pause_count[0]), int(dist.pause_count[1]) + 1))
    # A pause longer than the scene (short test scenes) silences all of it.
    lengths = np.minimum(np.round(rng.uniform(*dist.pause_s, count) * dist.fs).astype(np.int64), n)
    first = int(round(dist.pause_after_s * dist.fs))  # 0 by default: the formula of version 0
    if first >= n:  # a scene shorter than pause_after_s (short test scenes) has no pause
        return ()
    lengths = np.minimum(lengths, n - first)
    starts = first + np.floor(rng.uniform(0.0, 1.0, count) * (n - first - lengths + 1)).astype(np.int64)
    return tuple(sorted((int(a), int(a + b)) for a, b in zip(starts, lengths)))


def hold_during_pauses(points: np.ndarray, pauses: Sequence[tuple[int, int]], n_samples: int) -> np.ndarray:
    """The trajectory ``(S, 3)`` re-timed so that the talker stands still while silent.

    Point ``i`` stands for its segment's centre sample ``c``; it moves to where the original path
    is after the fraction ``a(c) / a(n)`` of the talking time, ``a(t)`` being the samples before
    ``t`` outside every pause (``pauses``: sample intervals, may overlap). So the whole path is
    walked while talking, in the same order, and points inside a pause share one position.
    """
    S = points.shape[0]
    bounds = segment_bounds(n_samples, S)
    centres = (bounds[:-1] + bounds[1:]) / 2.0
    silent = np.zeros(n_samples + 1, dtype=np.int64)  # +1 at a pause's start, -1 at its end
    for a, b in pauses:
        silent[a] += 1
        silent[b] -= 1
    talking = np.cumsum(np.concatenate([[0], np.cumsum(silent[:-1]) == 0]))  # a(t) for t = 0..n
    total = talking[-1]
    if total == 0:  # silent throughout: nowhere to walk
        return np.repeat(points[:1], S, axis=0)
    a_c = np.interp(centres, np.arange(n_samples + 1), talking)
    u = (a_c - a_c[0]) / max(a_c[-1] - a_c[0], 1e-12) * (S - 1)  # fractional index into the path
    idx = np.arange(S)
    return np.stack([np.interp(u, idx, points[:, k]) for k in range(3)], axis=1)
