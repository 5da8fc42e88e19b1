"""A miniature LOCATA corpus in the official format, simulated by doabench (for tests and demos).

:func:`write_fixture` lays out ``<root>/<split>/task<T>/recording<N>/benchmark2/`` with every file
the reader uses, written as LOCATA writes them (docs/locata.md): 48 kHz WAVs, tab-separated
tables with a header line and ``year month day hour minute second`` time columns, pose tables with
``x y z``, ``ref_vec_*``, ``rotation_11..33`` and (arrays) ``mic<k>_x/y/z`` world positions at
120 Hz, ``required_time.txt`` with ``valid_flag`` and ``VAD_benchmark2_<name>.txt``.

Scenes (world frame, a 6 x 5 x 3 m room, NAO geometry):

* task 1: static loudspeaker, static array with a non-identity rotation (yaw 35, pitch 10,
  roll -5 degrees);
* task 3: talker on an arc around a static array rotated by -50 degrees;
* task 5: talker on an arc while the array translates 0.7 m and turns by 60 degrees.

Audio: speech (the embedded clips) or noise bursts at 16 kHz, propagated to the moving
microphones either with doabench's room simulator (``simulator="builtin"`` or another backend name,
segment-wise, 0.25 s Hann-crossfaded segments) or in free field with exact time-varying fractional delays
(``"freefield"``), white noise added, then upsampled to 48 kHz with ``resample_poly``. The clocks
differ on purpose: poses and required times start 4 ms before the array audio, the source audio
10 ms before; a block of required times is flagged invalid.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import soundfile as sf

from doabench.arrays import get_array
from doabench.errors import ConfigError
from doabench.geometry import SPEED_OF_SOUND, normalize

FS_CORPUS = 48000
FS_SIM = 16000
POSE_RATE = 120.0
POSE_LEAD_S = 0.004  # poses and required times start this much before the array audio
SOURCE_LEAD_S = 0.010  # the source recording starts this much before the array audio
ROOM_DIMS = (6.0, 5.0, 3.0)
DEFAULT_START = "2017-09-20T15:40:25.068"
SOURCE_NAMES = {1: "loudspeaker1", 3: "talker1", 5: "talker1"}
TIME_HEADER = ("year", "month", "day", "hour", "minute", "second")


def rotation_matrix(yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """Local-to-world rotations ``Rz(yaw) Ry(pitch) Rx(roll)``, angles ``(N,)`` rad -> ``(N, 3, 3)``."""
    cy, sy, cp, sp, cr, sr = (f(a) for a in (yaw, pitch, roll) for f in (np.cos, np.sin))
    r = np.empty(np.shape(yaw) + (3, 3))
    r[..., 0, 0] = cy * cp
    r[..., 0, 1] = cy * sp * sr - sy * cr
    r[..., 0, 2] = cy * sp * cr + sy * sr
    r[..., 1, 0] = sy * cp
    r[..., 1, 1] = sy * sp * sr + cy * cr
    r[..., 1, 2] = sy * sp * cr - cy * sr
    r[..., 2, 0] = -sp
    r[..., 2, 1] = cp * sr
    r[..., 2, 2] = cp * cr
    return r


@dataclass(frozen=True)
class Motion:
    """Kinematics of one fixture recording as functions of time ``t (N,)`` in seconds since the
    first array-audio sample."""

    array_position: Callable[[np.ndarray], np.ndarray]  # (N,) -> (N, 3)
    array_rotation: Callable[[np.ndarray], np.ndarray]  # (N,) -> (N, 3, 3) local-to-world
    source_position: Callable[[np.ndarray], np.ndarray]  # (N,) -> (N, 3)

    def directions(self, t: np.ndarray) -> np.ndarray:
        """True array-frame unit vectors ``(N, 3)``: ``R(t)^T (s(t) - p(t))``."""
        r = self.array_rotation(t)
        return normalize(np.einsum("nji,nj->ni", r, self.source_position(t) - self.array_position(t)))


def task_motion(task: int, duration_s: float) -> Motion:
    """The scripted scene of a fixture task (1, 3 or 5; see the module docstring)."""
    d = float(duration_s)
    ones = lambda t: np.ones_like(np.asarray(t, np.float64))  # noqa: E731
    if task == 1:
        p0, s0 = np.array([3.0, 2.4, 1.4]), np.array([4.6, 3.5, 1.7])
        return Motion(lambda t: p0 * ones(t)[:, None],
                      lambda t: rotation_matrix(math.radians(35) * ones(t), math.radians(10) * ones(t),
                                                math.radians(-5) * ones(t)),
                      lambda t: s0 * ones(t)[:, None])
    if task == 3:
        p0 = np.array([3.0, 2.4, 1.4])

        def source(t):
            phi = np.radians(10.0 + 90.0 * np.asarray(t) / d)
            return np.stack([3.0 + 1.6 * np.cos(phi), 2.4 + 1.6 * np.sin(phi), 1.6 + 0.2 * np.sin(phi)], -1)

        return Motion(lambda t: p0 * ones(t)[:, None],
                      lambda t: rotation_matrix(math.radians(-50) * ones(t), 0 * ones(t), 0 * ones(t)), source)
    if task == 5:
        def array_position(t):
            u = np.asarray(t) / d
            return np.stack([2.6 + 0.6 * u, 2.2 + 0.4 * u, 1.3 + 0.0 * u], -1)

        def array_rotation(t):
            u = np.asarray(t) / d
            return rotation_matrix(np.radians(20.0 + 60.0 * u), math.radians(5) * ones(t), 0 * ones(t))

        def source(t):
            phi = np.radians(140.0 - 80.0 * np.asarray(t) / d)
            return np.stack([3.0 + 1.7 * np.cos(phi), 2.5 + 1.7 * np.sin(phi), 1.7 + 0.0 * phi], -1)

        return Motion(array_position, array_rotation, source)
    raise ConfigError(f"fixture tasks are 1, 3 and 5, not {task}")


@dataclass
class FixtureRecording:
    """What :func:`write_fixture` wrote for one recording, with its truth.

    ``motion.directions(t)`` gives the true array-frame directions at times ``t`` (seconds since the
    first array-audio sample); ``vad`` ``(L16,)`` is the clean source's VAD on the 16 kHz grid of
    the array audio; ``invalid_s`` the (start, end) of the required times flagged invalid.
    """

    path: Path
    task: int
    number: int
    source_name: str
    motion: Motion
    duration_s: float
    vad: np.ndarray
    invalid_s: tuple[float, float]
    simulator: str
    info: dict = field(default_factory=dict)


# -- the text format ----------------------------------------------------------------------------
def _calendar_columns(start: np.datetime64, offsets: np.ndarray) -> list[np.ndarray]:
    """Calendar columns of ``start + offsets`` seconds: year, month, day, hour, minute (int) and
    second (float), each ``(N,)``."""
    start_us = start.astype("datetime64[us]")
    day0 = start_us.astype("datetime64[D]")
    sod = (start_us - day0) / np.timedelta64(1, "s") + np.asarray(offsets, np.float64)
    days = np.floor(sod / 86400.0).astype(np.int64)
    sod = sod - days * 86400.0
    dates = day0 + days.astype("timedelta64[D]")
    years = dates.astype("datetime64[Y]")
    months = dates.astype("datetime64[M]")
    return [years.astype(np.int64) + 1970, (months - years.astype("datetime64[M]")).astype(np.int64) + 1,
            (dates - months.astype("datetime64[D]")).astype(np.int64) + 1,
            np.floor(sod / 3600.0).astype(np.int64), np.floor(np.mod(sod, 3600.0) / 60.0).astype(np.int64),
            np.mod(sod, 60.0)]


def write_table(path: Path, header: tuple[str, ...], columns: list[np.ndarray], formats: list[str]) -> None:
    """A tab-separated table with one header line; ``columns`` ``(N,)`` each, ``formats`` printf
    formats (``%d``, ``%.6f``)."""
    n = len(columns[0])
    cols = []
    for c, fmt in zip(columns, formats):
        values = np.asarray(c).tolist()
        if values and np.all(np.asarray(c) == values[0]):
            cols.append(itertools.repeat(fmt % values[0], n))  # constant columns are formatted once
        else:
            cols.append([fmt % v for v in values])
    with open(path, "w") as f:
        f.write("\t".join(header) + "\n")
        f.write("\n".join(map("\t".join, zip(*cols))) + "\n")


def write_time_table(path: Path, start: np.datetime64, offsets: np.ndarray, extra_header: tuple[str, ...] = (),
                     extra: list[np.ndarray] = (), extra_formats: list[str] = ()) -> None:
    """Time columns (seconds with 6 decimals) followed by ``extra`` columns."""
    write_table(path, TIME_HEADER + tuple(extra_header), _calendar_columns(start, offsets) + list(extra),
                ["%d"] * 5 + ["%.6f"] + list(extra_formats))


def write_pose_table(path: Path, start: np.datetime64, times: np.ndarray, position: np.ndarray,
                     rotation: np.ndarray, mics: np.ndarray | None = None) -> None:
    """``position_*`` table: time, ``x y z``, ``ref_vec_*`` (the local +y axis in the world, unused
    by the reader), ``rotation_ij`` and optional ``mic<k>_x/y/z`` ``(N, M, 3)`` world positions."""
    header = ["x", "y", "z", "ref_vec_x", "ref_vec_y", "ref_vec_z"]
    header += [f"rotation_{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3)]
    cols = [position[:, k] for k in range(3)] + [rotation[:, k, 1] for k in range(3)]
    cols += [rotation[:, i, j] for i in range(3) for j in range(3)]
    if mics is not None:
        header += [f"mic{m + 1}_{a}" for m in range(mics.shape[1]) for a in "xyz"]
        cols += [mics[:, m, a] for m in range(mics.shape[1]) for a in range(3)]
    write_time_table(path, start, times, tuple(header), cols, ["%.6f"] * len(cols))


# -- simulation -----------------------------------------------------------------------------------
def _signal(kind: str, rng: np.random.Generator, n: int, fs: int) -> tuple[np.ndarray, np.ndarray]:
    """Source ``(n,)`` float64 and its VAD ``(n,)`` bool: embedded speech or noise bursts."""
    if kind == "speech":
        from doabench.acoustics.speech import EmbeddedSpeechSource

        chunk = EmbeddedSpeechSource().sample(rng, n / fs, fs)
        x = chunk.signal.astype(np.float64)
        return x / (np.abs(x).max() + 1e-12) * 0.5, np.asarray(chunk.vad, bool)
    if kind == "noise":
        from scipy.signal import butter, sosfilt

        on = (np.arange(n) // int(0.6 * fs)) % 4 != 3  # 1.8 s bursts, 0.6 s pauses
        x = sosfilt(butter(4, [200, 4000], btype="band", fs=fs, output="sos"), rng.standard_normal(n))
        x = np.where(on, x, 0.0)
        return x / (np.abs(x).max() + 1e-12) * 0.5, on
    raise ConfigError(f"fixture signal {kind!r} is not speech or noise")


def _fractional_delay(x: np.ndarray, delay: np.ndarray, half: int = 8) -> np.ndarray:
    """``y[n] = x(n - delay[n])`` with a Hann-windowed sinc of ``2 * half`` taps (16: flat to about 6 kHz at 16 kHz); ``x`` ``(L,)``,
    ``delay`` ``(N,)`` in samples (time-varying), zero outside ``x``."""
    pos = np.arange(len(delay)) - delay
    base = np.floor(pos).astype(np.int64)
    j = np.arange(-half + 1, half + 1)
    arg = (pos - base)[:, None] - j[None, :]  # distance of each tap from the wanted position
    kernel = np.sinc(arg) * (0.5 + 0.5 * np.cos(np.pi * arg / half))
    idx = base[:, None] + j[None, :]
    ok = (idx >= 0) & (idx < len(x))
    return np.sum(np.where(ok, x[np.clip(idx, 0, len(x) - 1)], 0.0) * kernel, axis=1)


def _freefield(source: np.ndarray, lead: int, t: np.ndarray, motion: Motion, local: np.ndarray,
               fs: int) -> np.ndarray:
    """Free-field propagation to moving microphones: ``(M, N)`` at times ``t (N,)``; ``source``
    starts ``lead`` samples before ``t[0]``."""
    p, r, s = motion.array_position(t), motion.array_rotation(t), motion.source_position(t)
    mics = p[:, None, :] + np.einsum("nij,mj->nmi", r, local)  # (N, M, 3) world positions
    dist = np.linalg.norm(s[:, None, :] - mics, axis=-1)  # (N, M)
    out = np.empty((local.shape[0], len(t)))
    for m in range(local.shape[0]):  # one mic at a time bounds the (N, taps) temporaries
        out[m] = _fractional_delay(source, dist[:, m] / SPEED_OF_SOUND * fs - lead) / np.maximum(dist[:, m], 0.1)
    return out


def _room_simulated(source: np.ndarray, lead: int, t: np.ndarray, motion: Motion, local: np.ndarray, fs: int,
                    backend: str, t60: float, seed: int, segment_s: float = 0.25) -> np.ndarray:
    """Room simulation with a doabench backend's RIRs, segment by segment: the signal is split
    into 50 %-overlapping Hann-windowed segments (the windows sum to one); segment ``k`` is
    convolved with the RIRs from the source to the microphones at the segment's centre time and
    the results are overlap-added. A static array needs one RIR call for all segments."""
    from scipy.signal import oaconvolve

    from doabench.acoustics.room import Room
    from doabench.acoustics.simulators import get_simulator

    sim = get_simulator(backend)
    room = Room(ROOM_DIMS, t60)
    n, hop = len(t), int(segment_s * fs)
    starts = np.arange(-hop, n, hop)
    centres = t[np.clip(starts + hop, 0, n - 1)]
    sources = motion.source_position(centres)  # (K, 3)
    mics = motion.array_position(centres)[:, None, :] + np.einsum("kij,mj->kmi", motion.array_rotation(centres),
                                                                  local)  # (K, M, 3)
    if np.allclose(mics, mics[:1]):
        rirs = np.asarray(sim.rirs(room, sources, mics[0], fs, seed=seed), np.float64)  # (K, M, taps)
    else:
        rirs = [np.asarray(sim.rirs(room, sources[k:k + 1], mics[k], fs, seed=seed + k), np.float64)[0]
                for k in range(len(starts))]
    sig = source[lead:lead + n]
    window = np.hanning(2 * hop + 1)[:-1]  # periodic Hann: 50 % overlapped copies sum to one
    out = np.zeros((local.shape[0], n + max(r.shape[-1] for r in rirs) + 2 * hop))
    for k, start in enumerate(starts):
        lo, hi = max(start, 0), min(start + 2 * hop, n)
        seg = sig[lo:hi] * window[lo - start:hi - start]
        if hi > lo and np.any(seg):
            y = oaconvolve(seg[None, :], rirs[k], axes=-1)  # (M, len + taps - 1)
            out[:, lo:lo + y.shape[1]] += y
    return out[:, :n]


# -- the writer -----------------------------------------------------------------------------------
def write_recording(root: Path, split: str, task: int, number: int, duration_s: float, simulator: str,
                    t60: float, snr_db: float, seed: int, vad_files: bool, signal: str,
                    start: np.datetime64) -> FixtureRecording:
    """Simulate and write one recording folder (see :func:`write_fixture`)."""
    rng = np.random.default_rng([int(seed), int(task), int(number)])
    array = get_array("benchmark2")
    motion = task_motion(task, duration_s)
    name = SOURCE_NAMES[task]
    folder = Path(root) / split / f"task{task}" / f"recording{number}" / "benchmark2"
    folder.mkdir(parents=True, exist_ok=True)

    n16 = int(round(duration_s * FS_SIM))
    lead16 = int(round(SOURCE_LEAD_S * FS_SIM))
    source, vad = _signal(signal, rng, n16 + lead16, FS_SIM)
    t16 = np.arange(n16) / FS_SIM
    if simulator == "freefield":
        mix = _freefield(source, lead16, t16, motion, array.positions, FS_SIM)
    else:
        mix = _room_simulated(source, lead16, t16, motion, array.positions, FS_SIM, simulator, t60,
                              int(rng.integers(2**31)))
    active = vad[lead16:]
    power = float(np.mean(mix[:, active] ** 2)) if active.any() else float(np.mean(mix ** 2))
    mix = mix + rng.standard_normal(mix.shape) * math.sqrt(power / 10 ** (snr_db / 10))
    mix *= 0.5 / (np.abs(mix).max() + 1e-12)

    from scipy.signal import resample_poly

    up = FS_CORPUS // FS_SIM
    audio48 = resample_poly(mix, up, 1, axis=1)
    source48 = resample_poly(source, up, 1)
    sf.write(folder / "audio_array_benchmark2.wav", audio48.T, FS_CORPUS, subtype="PCM_16")
    write_time_table(folder / "audio_array_timestamps_benchmark2.txt", start, np.arange(audio48.shape[1]) / FS_CORPUS)
    sf.write(folder / f"audio_source_{name}.wav", source48, FS_CORPUS, subtype="PCM_16")
    write_time_table(folder / f"audio_source_timestamps_{name}.txt", start,
                     np.arange(len(source48)) / FS_CORPUS - lead16 / FS_SIM)

    pose_t = np.arange(-POSE_LEAD_S, duration_s + POSE_LEAD_S + 1.0 / POSE_RATE, 1.0 / POSE_RATE)
    p, r = motion.array_position(pose_t), motion.array_rotation(pose_t)
    mics = p[:, None, :] + np.einsum("nij,mj->nmi", r, array.positions)
    write_pose_table(folder / "position_array_benchmark2.txt", start, pose_t, p, r, mics)
    s = motion.source_position(pose_t)
    write_pose_table(folder / f"position_source_{name}.txt", start, pose_t, s,
                     np.broadcast_to(np.eye(3), (len(pose_t), 3, 3)))
    invalid = (0.45 * duration_s, 0.55 * duration_s)
    valid = ~((pose_t >= invalid[0]) & (pose_t < invalid[1]))
    write_time_table(folder / "required_time.txt", start, pose_t, ("valid_flag",), [valid.astype(np.int64)], ["%d"])
    if vad_files:
        vad48 = np.repeat(active, up)[: audio48.shape[1]]
        write_table(folder / f"VAD_benchmark2_{name}.txt", ("VAD",), [vad48.astype(np.int64)], ["%d"])
    return FixtureRecording(folder, task, number, name, motion, duration_s, active, invalid, simulator,
                            {"snr_db": snr_db, "t60": t60 if simulator != "freefield" else 0.0, "signal": signal})


def write_fixture(root: str | Path, tasks: tuple[int, ...] = (1, 3, 5), split: str = "dev", recordings: int = 1,
                  duration_s: float = 4.0, simulator: str = "builtin", t60: float = 0.2, snr_db: float = 30.0,
                  seed: int = 0, vad_files: bool = True, signal: str = "speech",
                  start: str = DEFAULT_START) -> list[FixtureRecording]:
    """Write a miniature LOCATA corpus under ``root`` and return its recordings with their truth.

    ``tasks``: fixture scenes 1, 3, 5; ``recordings`` per task (numbered from 1); ``simulator``:
    ``"freefield"`` (exact moving delays, no room) or a doabench backend name (``"builtin"``);
    ``t60`` for the room; ``snr_db`` of the added white noise; ``vad_files=False`` leaves out the
    VAD files (the reader then runs the WebRTC VAD on the source audio); ``signal``: ``"speech"``
    (embedded clips) or ``"noise"`` (bursts); ``start``: the calendar time of the first array sample.
    """
    origin = np.datetime64(start)
    return [write_recording(Path(root), split, int(task), n, duration_s, simulator, t60, snr_db, seed, vad_files,
                            signal, origin)
            for task in tasks for n in range(1, recordings + 1)]
