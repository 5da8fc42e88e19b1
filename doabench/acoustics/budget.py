"""What simulating a scene costs in memory, checked before the work starts.

Two quantities set the cost. The T60 sets the room impulse responses: the image-source part lasts
``Tdiff = 0.2 T60`` and a whole response ``Tmax = (2/3) T60`` (:mod:`doabench.acoustics.room`),
and the images within reach of ``Tdiff`` grow with its cube over the room's volume, so a T60 of
50 s asks for hundreds of GiB before the first sample. The duration sets the signals. A scene
distribution whose costliest scene would need more memory than the machine has is refused with
one line naming the field and the estimate (:func:`check_fits`), before anything is drawn,
allocated or written; ``simulate``, every simulated task's episode source (``run``,
``make-dataset``, ``sweep``) and ``train`` check it.

The estimate is meant as a bound of the peak, not an exact count, and it is the engine's
(:func:`simulation_bytes`, ``backend``):

* ``builtin`` (and gpuRIR, whose image sources live on the GPU, and a plug-in simulator, of which
  nothing is known): the sizes of the builtin engine (:mod:`doabench.acoustics.rir`,
  :mod:`doabench.acoustics.convolution`) with allowance for responses held in float64. Its
  measured peaks (growth of the process's maximum resident size while rendering one scene) were
  35-86 % of it, from 20 s scenes at T60 1.3 s to a T60 of 6 s in a 3 x 3 x 2.5 m room.
* ``pyroomacoustics``: the builtin's, plus pyroomacoustics' own image sources up to Tdiff: every
  image of reflection order up to ``N`` (``(2N + 1)(2N^2 + 2N + 3) / 3`` of them), for up to
  8 sources a room, each image about ``224 + 32 M`` bytes with ``M`` microphones (measured at
  order 100, 1.35 million images of one source: 264, 523 and 824 bytes for 2, 12 and 24
  microphones; with 8 sources at order 58, 260 bytes an image for 12 microphones, so the count
  is an upper bound there).
* ``pyroomacoustics-full``: those images for one source a room, to the order of
  pyroomacoustics' ``inverse_sabine`` rule at Tmax (``ceil(c Tmax / R) - 1``, ``R`` the smallest
  of ``l1 l2 / sqrt(l1^2 + l2^2)`` over the room's pairs of sides): the order grows as ``c T60 /
  L`` and the images as its cube, so ``--t60 5`` in a small room asks for hundreds of millions of
  images (tens of GiB), which pyroomacoustics' C++ core would die on (``std::bad_alloc``).
* ``torchrir``: torchrir walks its image grid in chunks of bounded size, so its image count sets
  its time, not its memory; its responses (float32, with the diffuse tail's temporaries: measured
  13 bytes a tap, counted 16) and a fixed allowance for the chunks (48 MiB) are counted.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Mapping, Sequence

from doabench.acoustics.rir_model import SINC_HALF
from doabench.acoustics.room import diffuse_start, max_time
from doabench.errors import ConfigError
from doabench.geometry import SPEED_OF_SOUND

if TYPE_CHECKING:
    from doabench.acoustics.scenes import Scene, SceneDistribution

# Bytes per candidate image of enumerate_images: its three int64 index grids plus the float64
# temporaries of the pruning, then the kept images' float64 arrays.
_IMAGE_BYTES = 64
# Bytes per tap of a point's response: float32 in the builtin engine, float64 in pyroomacoustics.
_TAP_BYTES = 8
# Bytes per sample and microphone of the signals held at once: the reverberant speech, the noise,
# their sum and a directional noise (float32), the per-point convolution frames and its output.
_SAMPLE_BYTES_PER_MIC = 24
# Bytes per sample of the one-channel signals: speech (float64), per-sample truth directions
# (3 float64), the VAD and the segment index tensors of the moving-source convolution.
_SAMPLE_BYTES = 64
# The diffuse tail (one per microphone) and the spectra of its convolution with the signal.
_TAIL_BYTES_PER_TAP = 16
# Bytes per pyroomacoustics image source: a fixed part and a part per microphone (its visibility
# and the distances and delays of compute_rir), measured at order 100 with 2, 12 and 24 microphones.
_PRA_IMAGE_BYTES = 224
_PRA_IMAGE_BYTES_PER_MIC = 32
# pyroomacoustics sources per room in the ``pyroomacoustics`` backend (its SOURCES_PER_ROOM).
_PRA_SOURCES_PER_ROOM = 8
# torchrir: bytes per tap of the responses (float32, the tail's temporaries, the per-call batch)
# and its image chunks' temporaries (about ten tensors of 2**18 elements, with slack).
_TORCHRIR_TAP_BYTES = 16
_TORCHRIR_CHUNK_BYTES = 48 << 20
# cgroup limits of the process's memory (v2, then v1): a container can have less than the machine.
_CGROUP_LIMITS = ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes")


@dataclass(frozen=True)
class SimulationCost:
    """Estimated peak memory of simulating one scene, in bytes (floats: absurd inputs give numbers
    beyond any integer type), by what drives it: ``images`` (the T60 and the room), ``responses``
    (the T60 times the trajectory points) and ``signals`` (the duration)."""

    images: float
    responses: float
    signals: float

    @property
    def total(self) -> float:
        return self.images + self.responses + self.signals


def image_candidates(dims: tuple[float, float, float], horizon_m: float) -> float:
    """Images :func:`~doabench.acoustics.rir_model.enumerate_images` considers for a ``horizon_m``
    reach in a room of ``dims`` metres: per axis ``2 (2 n + 1)`` with ``n = ceil(horizon / 2L) + 1``
    (bounded above here without the ceiling, which overflows on absurd inputs)."""
    return math.prod(2.0 * (2.0 * (horizon_m / (2.0 * length) + 2.0) + 1.0) for length in dims)


def octahedral_images(order: float) -> float:
    """Images of reflection order up to ``order`` in a shoebox room: the integer points of the
    octahedron ``|i| + |j| + |k| <= order``, ``(2N + 1)(2N^2 + 2N + 3) / 3`` (a float: absurd orders
    overflow every integer type)."""
    n = max(0.0, float(order))
    return (2.0 * n + 1.0) * (2.0 * n * n + 2.0 * n + 3.0) / 3.0


def pra_full_order(dims: tuple[float, float, float], t60: float) -> float:
    """The reflection order the ``pyroomacoustics-full`` backend asks of pyroomacoustics
    (``inverse_sabine`` at Tmax, falling back to the T60 where its absorption check refuses Tmax,
    as :meth:`~doabench.acoustics.backends.pra_full.PyroomacousticsFullSimulator.image_order`
    does), computed here without importing pyroomacoustics."""
    if t60 <= 0:
        return 0.0
    pairs = ((dims[0], dims[1]), (dims[0], dims[2]), (dims[1], dims[2]))
    radius = min(a * b / math.hypot(a, b) for a, b in pairs)
    volume = math.prod(dims)
    surface = 2.0 * sum(a * b for a, b in pairs)
    t = max_time(t60)
    if 24.0 * math.log(10.0) * volume / (SPEED_OF_SOUND * surface * t) > 1.0:
        t = t60  # inverse_sabine refuses so short a time: the backend asks for the T60's order
    return max(0.0, math.ceil(SPEED_OF_SOUND * t / radius - 1.0))


def _pra_order(dims: tuple[float, float, float], horizon_m: float) -> float:
    """The reflection order the ``pyroomacoustics`` backend asks for the images within reach of
    Tdiff (``horizon_m``): along each axis an image ``d`` metres away reflects about ``d / L``
    times (plus the room's own span)."""
    return horizon_m * math.sqrt(sum(1.0 / length**2 for length in dims)) + 9.0


def _horizon_m(t60: float, fs: int) -> float:
    """How far the image sources of the responses' early part reach, in metres."""
    return (diffuse_start(t60) * fs + SINC_HALF) / fs * SPEED_OF_SOUND


def _pra_image_bytes(order: float, n_mics: int, sources_per_room: int) -> float:
    return octahedral_images(order) * sources_per_room * (_PRA_IMAGE_BYTES + _PRA_IMAGE_BYTES_PER_MIC * n_mics)


def simulation_bytes(dims: tuple[float, float, float], t60: float, n_mics: int, n_points: int,
                     duration_s: float, fs: int, backend: str = "builtin") -> SimulationCost:
    """The peak memory of simulating one scene with the engine ``backend`` (module docstring): a
    room of ``dims`` metres with ``t60`` seconds of reverberation, ``n_mics`` microphones, a
    trajectory of ``n_points`` points and ``duration_s`` seconds of audio at ``fs`` Hz."""
    n_taps = max_time(t60) * fs
    horizon_m = _horizon_m(t60, fs)
    # Each point's response is convolved with its segment zero-padded to a common FFT length, so
    # the points' responses also hold the samples of the whole signal once.
    per_sample = _SAMPLE_BYTES_PER_MIC * n_mics + _SAMPLE_BYTES + _TAP_BYTES * n_mics
    signals = duration_s * fs * per_sample
    builtin_images = _IMAGE_BYTES * image_candidates(dims, horizon_m) + _TAIL_BYTES_PER_TAP * n_mics * n_taps
    responses = _TAP_BYTES * n_mics * n_points * n_taps
    if backend == "pyroomacoustics":
        order = _pra_order(dims, horizon_m)
        sources = max(1, min(n_points, _PRA_SOURCES_PER_ROOM))
        return SimulationCost(builtin_images + _pra_image_bytes(order, n_mics, sources), responses, signals)
    if backend == "pyroomacoustics-full":
        # one source a room; its RIR lists (float64, per microphone) beside the images
        images = _pra_image_bytes(pra_full_order(dims, t60), n_mics, 1) + 2 * _TAP_BYTES * n_mics * n_taps
        return SimulationCost(images, responses, signals)
    if backend == "torchrir":
        return SimulationCost(float(_TORCHRIR_CHUNK_BYTES), _TORCHRIR_TAP_BYTES * n_mics * n_points * n_taps, signals)
    return SimulationCost(builtin_images, responses, signals)


def machine_memory() -> int | None:
    """This process's memory in bytes: the physical memory, or a smaller cgroup limit (None where
    the system does not say)."""
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        return None
    for name in _CGROUP_LIMITS:
        try:
            limit = Path(name).read_text().strip()
        except OSError:
            continue
        if limit.isdigit():
            total = min(total, int(limit))
    return total if total > 0 else None


def _gib(n_bytes: float) -> str:
    """``n_bytes`` in GiB, three significant digits."""
    return f"{n_bytes / 2**30:.3g} GiB"


def _estimate(n_bytes: float) -> str:
    """An estimate in words: ``about 874 GiB``, or a bound where it is too large for a float."""
    return f"about {_gib(n_bytes)}" if math.isfinite(n_bytes) else "more than 1e+300 GiB"


def scene_fields(prefix: str) -> dict[str, str]:
    """How :func:`check_fits` names a distribution's fields: ``{prefix} t60`` and so on."""
    return {name: f"{prefix} {name}" for name in ("t60", "n_points", "duration_s")}


def _seconds(name: str, value: float) -> str:
    """A field and its value as the user wrote them: ``--t60 50``, ``scene t60 50 s``."""
    return f"{name} {value:g}" + ("" if name.startswith("--") else " s")


def costliest_scene(dist: SceneDistribution, n_mics: int, backend: str = "builtin") -> SimulationCost:
    """:func:`simulation_bytes` of the costliest scene ``dist`` can draw on ``backend``: the
    smallest room (the most images within reach) at the highest T60, a moving source over every
    trajectory point."""
    return simulation_bytes(dist.room_min, dist.t60[1], n_mics, dist.n_points, dist.duration_s, dist.fs, backend)


def _field(dist: SceneDistribution, cost: SimulationCost, names: Mapping[str, str]) -> str:
    """The field that drives ``cost`` most, with its value, as ``names`` spells it."""
    driver = max((cost.images, "t60"), (cost.responses, "n_points"), (cost.signals, "duration_s"))[1]
    if driver == "t60":
        up_to = " up to" if dist.t60[0] != dist.t60[1] else ""
        return _seconds(names["t60"] + up_to, dist.t60[1])
    if driver == "n_points" and names["n_points"] != names["duration_s"]:
        return f"{names['n_points']} {dist.n_points}"
    return _seconds(names["duration_s"], dist.duration_s)  # the points follow the duration there


def check_fits(dist: SceneDistribution, n_mics: int, fields: Mapping[str, str] | None = None,
               backend: str = "builtin") -> None:
    """Raise :class:`ConfigError` when simulating the costliest scene of ``dist`` with ``n_mics``
    microphones on the engine ``backend`` would need more memory than this machine has. The
    message names the field that drives the cost most (``t60``, ``n_points`` or ``duration_s``, as
    ``fields`` spells them, e.g. ``{"t60": "--t60"}``; default ``scene t60`` ...) and the estimate.
    A ``n_points`` spelt like ``duration_s`` follows the duration (``simulate --duration`` scales
    the trajectory)."""
    available = machine_memory()
    cost = costliest_scene(dist, n_mics, backend)
    if available is None or cost.total <= available:
        return
    names = {**scene_fields("scene"), **(fields or {})}
    engine = ""
    if backend in ("pyroomacoustics", "pyroomacoustics-full") and cost.images >= max(cost.responses, cost.signals):
        order = (pra_full_order(dist.room_min, dist.t60[1]) if backend == "pyroomacoustics-full" else None)
        engine = (f"{backend}'s image sources to reflection order {order:.3g}, " if order is not None
                  else f"{backend}'s image sources, ")
    elif backend != "builtin":
        engine = f"the {backend} engine: "
    detail = (f"{engine}room impulse responses of {max_time(dist.t60[1]):.3g} s for {n_mics} microphones x "
              f"{dist.n_points} trajectory points, {dist.duration_s:.3g} s of audio")
    raise ConfigError(f"{_field(dist, cost, names)}: simulating a scene needs {_estimate(cost.total)} of memory "
                      f"({detail}), more than the {_gib(available)} of this machine")


# -- time ------------------------------------------------------------------------------------------
# What simulating a scene costs in time is not bounded (a torchrir scene at T60 5 s fits in memory
# and takes hours), but a job whose engine takes more than SLOW_SCENE_S a scene says so, with its
# estimate, before it starts. The model: seconds of one CPU thread per image source, microphone and
# trajectory point, each engine counting its images as its memory estimate does
# (:func:`engine_images`), plus the per-sample work every engine shares (convolutions, the tail).
# Calibrated from process CPU times of one thread on an AMD EPYC core rendering scenes 1000 and 1001
# of the paper's distribution (rooms 6.8 x 5.7 x 6.0 m at T60 0.84 s and 5.8 x 6.8 x 2.8 m at
# T60 1.21 s; 12 microphones, 4 trajectory points, beside a training run): pyroomacoustics-full
# 0.85 and 12.4 s (1.3e-7 and 1.5e-7 s a unit), torchrir 0.62 and 3.0 s (1.4e-6, 1.2e-6),
# pyroomacoustics 0.08 and 0.45 s (7.1e-8, 7.8e-8); and from docs/performance.md's 156-point
# timings on an idle machine (pyroomacoustics-full 31.3 s at T60 0.84 s: 1.25e-7; torchrir 47.5 s
# over scenes 1000-1002: 1.1e-6; builtin 0.2 s, 47 % of it image sources: 1.1e-9 a candidate image,
# the rest 3e-8 s a sample and microphone). Within a factor of 2 of what was measured; threads,
# another CPU or a GPU change it.
_SECONDS_PER_IMAGE = {"builtin": 1.1e-9, "pyroomacoustics": 7.5e-8, "pyroomacoustics-full": 1.4e-7,
                      "torchrir": 1.3e-6}
_SECONDS_PER_SAMPLE_PER_MIC = 3e-8
#: an engine slower than this per scene (seconds) says how long a job will take before it starts
SLOW_SCENE_S = 60.0


def engine_images(dims: tuple[float, float, float], t60: float, fs: int, backend: str) -> float | None:
    """Image sources the engine ``backend`` computes for one point of a room of ``dims`` metres at
    ``t60`` (None for an engine the model does not know: gpuRIR, a plug-in): the builtin's
    candidates within reach of Tdiff, pyroomacoustics' octahedron of the order of Tdiff,
    pyroomacoustics-full's of its ``inverse_sabine`` order at Tmax, torchrir's image grid of Tdiff
    (``2 ceil(c Tdiff / L) + 1`` per axis)."""
    if t60 <= 0:
        return 1.0
    if backend == "builtin":
        return image_candidates(dims, _horizon_m(t60, fs))
    if backend == "pyroomacoustics":
        return octahedral_images(_pra_order(dims, _horizon_m(t60, fs)))
    if backend == "pyroomacoustics-full":
        return octahedral_images(pra_full_order(dims, t60))
    if backend == "torchrir":
        reach = SPEED_OF_SOUND * diffuse_start(t60)
        return math.prod(2.0 * math.ceil(reach / length) + 1.0 if math.isfinite(reach / length) else math.inf
                         for length in dims)
    return None


def simulation_seconds(dims: tuple[float, float, float], t60: float, n_mics: int, n_points: float,
                       duration_s: float, fs: int, backend: str = "builtin") -> float | None:
    """Rough seconds of one CPU thread that simulating one scene takes on the engine ``backend``
    (the model above; None for an engine it does not know), for the sizes of
    :func:`simulation_bytes`."""
    images = engine_images(dims, t60, fs, backend)
    if images is None:
        return None
    return (_SECONDS_PER_IMAGE[backend] * images * n_mics * n_points
            + _SECONDS_PER_SAMPLE_PER_MIC * duration_s * fs * n_mics)


@dataclass(frozen=True)
class SceneTime:
    """Rough seconds of one CPU thread per scene a distribution draws on an engine: ``mean`` over
    its rooms, T60s and static or moving talkers, ``worst`` its costliest scene (the smallest room at
    the highest T60, a moving talker)."""

    engine: str
    mean: float
    worst: float


def scene_time(dist: SceneDistribution, n_mics: int, backend: str = "builtin") -> SceneTime | None:
    """:class:`SceneTime` of ``dist`` on ``backend`` (None for an engine the model does not know).
    The mean is taken over 64 fixed draws of the room and the T60 (uniform in their ranges, as the
    scenes draw them), with the talker's points weighted by how often a scene moves (a static
    talker heard by a static array is one point)."""
    import numpy as np

    worst = simulation_seconds(dist.room_min, dist.t60[1], n_mics, dist.n_points, dist.duration_s, dist.fs, backend)
    if worst is None:
        return None
    p_moving = 1.0 - dist.p_static * (1.0 - dist.walk_p) * (1.0 - dist.array_motion_p)
    points = p_moving * dist.n_points + (1.0 - p_moving)
    draws = np.random.default_rng(0).uniform(size=(64, 4))
    low, high = np.asarray(dist.room_min, float), np.asarray(dist.room_max, float)
    total = 0.0
    for u in draws:
        x, y, z = (float(v) for v in low + u[:3] * (high - low))
        dims = (x, y, z)
        t60 = dist.t60[0] + float(u[3]) * (dist.t60[1] - dist.t60[0])
        total += simulation_seconds(dims, t60, n_mics, points, dist.duration_s, dist.fs, backend) or 0.0
    return SceneTime(backend, total / len(draws), worst)


def _duration(seconds: float) -> str:
    """``40 s``, ``2.3 min``, ``5.1 h``, ``3.2 days``."""
    if not math.isfinite(seconds):
        return "longer than anyone can wait"
    if seconds >= 1.5 * 86400.0:
        return f"{seconds / 86400.0:.2g} days"
    if seconds >= 1.5 * 3600.0:
        return f"{seconds / 3600.0:.2g} h"
    if seconds >= 60.0:
        return f"{seconds / 60.0:.2g} min"
    return f"{seconds:.0f} s"


def time_note(engine: str, scene_seconds: Sequence[float], worst: float | None = None, workers: int = 1,
              what: str = "episode", group: str | None = None) -> str | None:
    """One line saying how long a job of these scenes takes on ``engine`` when its scenes take
    more than :data:`SLOW_SCENE_S` on average (None otherwise): ``scene_seconds`` are the
    estimates of the scenes still to simulate, ``worst`` the costliest scene's, ``workers`` the
    processes that share them, ``what`` names a scene (``episode``, ``trajectory``) and ``group``
    what the scenes make up (``an epoch``: "about 3 h for an epoch of 585 trajectories")."""
    if not scene_seconds:
        return None
    n = len(scene_seconds)
    total = float(sum(scene_seconds))
    mean = total / n
    if not mean > SLOW_SCENE_S:
        return None
    plural = what[:-1] + "ies" if what.endswith("y") else what + "s"
    scenes = f"{n} {plural}" if n > 1 else f"this {what}"
    job = f"about {_duration(total)} for " + (f"{group} of {scenes}" if group else
                                              scenes if n == 1 else f"these {scenes}")
    if workers > 1 and n > 1:
        job += f" ({_duration(total / workers)} with {workers} workers)"
    each = ""
    if n > 1:
        upto = f", up to {_duration(worst)} for its costliest scene" if worst is not None and worst > 1.5 * mean else ""
        each = f"about {_duration(mean)} a{'n' if what[0] in 'aeiou' else ''} {what}{upto}; "
    return (f"note: the {engine} engine is slow here: {each}{job} (a rough estimate from its image sources, "
            "for one CPU thread; stop with Ctrl-C)")


def drawn_scene_note(scene: Scene, backend: str, device: str | None = None) -> str | None:
    """:func:`time_note` of one drawn ``scene`` on ``backend`` (``simulate``): its own room, T60
    and points; None when it takes less than a minute, on a GPU or on an engine the model does not
    know."""
    if device is not None and not str(device).startswith("cpu"):
        return None
    points = len(scene.trajectory) if scene.moving_array else len(scene.source_positions)
    seconds = simulation_seconds(scene.room.dims, scene.room.t60, len(scene.mic_positions), points,
                                 scene.duration_s, scene.fs, backend)
    return None if seconds is None else time_note(backend, [seconds], what="scene")
