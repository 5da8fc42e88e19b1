"""What simulating a scene costs in memory, checked before the work starts.

Two quantities set the cost. The T60 sets the room impulse responses: the image-source part lasts
``Tdiff = 0.2 T60`` and a whole response ``Tmax = (2/3) T60`` (:mod:`doabench.acoustics.room`),
and the images within reach of ``Tdiff`` grow with its cube over the room's volume, so a T60 of
50 s asks for hundreds of GiB before the first sample. The duration sets the signals. A scene
distribution whose costliest scene would need more memory than the machine has is refused with
one line naming the field and the estimate (:func:`check_fits`), before anything is drawn,
allocated or written; ``simulate``, every simulated task's episode source (``run``,
``make-dataset``, ``sweep``) and ``train`` check it.

The estimate is meant as a bound of the peak, not an exact count: the sizes below are those of the
builtin engine (:mod:`doabench.acoustics.rir`, :mod:`doabench.acoustics.convolution`) with
allowance for the other backends, which hold whole responses in float64. The builtin engine's
measured peaks (growth of the process's maximum resident size while rendering one scene) were
35-86 % of it, from 20 s scenes at T60 1.3 s to a T60 of 6 s in a 3 x 3 x 2.5 m room.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Mapping

from doabench.acoustics.rir import SINC_HALF
from doabench.acoustics.room import diffuse_start, max_time
from doabench.errors import ConfigError
from doabench.geometry import SPEED_OF_SOUND

if TYPE_CHECKING:
    from doabench.acoustics.scenes import SceneDistribution

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
    """Images :func:`~doabench.acoustics.rir.enumerate_images` considers for a ``horizon_m``
    reach in a room of ``dims`` metres: per axis ``2 (2 n + 1)`` with ``n = ceil(horizon / 2L) + 1``
    (bounded above here without the ceiling, which overflows on absurd inputs)."""
    return math.prod(2.0 * (2.0 * (horizon_m / (2.0 * length) + 2.0) + 1.0) for length in dims)


def simulation_bytes(dims: tuple[float, float, float], t60: float, n_mics: int, n_points: int,
                     duration_s: float, fs: int) -> SimulationCost:
    """The peak memory of simulating one scene: a room of ``dims`` metres with ``t60`` seconds of
    reverberation, ``n_mics`` microphones, a trajectory of ``n_points`` points and ``duration_s``
    seconds of audio at ``fs`` Hz."""
    n_taps = max_time(t60) * fs
    horizon_m = (diffuse_start(t60) * fs + SINC_HALF) / fs * SPEED_OF_SOUND
    # Each point's response is convolved with its segment zero-padded to a common FFT length, so
    # the points' responses also hold the samples of the whole signal once.
    per_sample = _SAMPLE_BYTES_PER_MIC * n_mics + _SAMPLE_BYTES + _TAP_BYTES * n_mics
    return SimulationCost(
        images=_IMAGE_BYTES * image_candidates(dims, horizon_m) + _TAIL_BYTES_PER_TAP * n_mics * n_taps,
        responses=_TAP_BYTES * n_mics * n_points * n_taps,
        signals=duration_s * fs * per_sample,
    )


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


def costliest_scene(dist: SceneDistribution, n_mics: int) -> SimulationCost:
    """:func:`simulation_bytes` of the costliest scene ``dist`` can draw: the smallest room (the
    most images within reach) at the highest T60, a moving source over every trajectory point."""
    return simulation_bytes(dist.room_min, dist.t60[1], n_mics, dist.n_points, dist.duration_s, dist.fs)


def _field(dist: SceneDistribution, cost: SimulationCost, names: Mapping[str, str]) -> str:
    """The field that drives ``cost`` most, with its value, as ``names`` spells it."""
    driver = max((cost.images, "t60"), (cost.responses, "n_points"), (cost.signals, "duration_s"))[1]
    if driver == "t60":
        up_to = " up to" if dist.t60[0] != dist.t60[1] else ""
        return _seconds(names["t60"] + up_to, dist.t60[1])
    if driver == "n_points" and names["n_points"] != names["duration_s"]:
        return f"{names['n_points']} {dist.n_points}"
    return _seconds(names["duration_s"], dist.duration_s)  # the points follow the duration there


def check_fits(dist: SceneDistribution, n_mics: int, fields: Mapping[str, str] | None = None) -> None:
    """Raise :class:`ConfigError` when simulating the costliest scene of ``dist`` with ``n_mics``
    microphones would need more memory than this machine has. The message names the field that
    drives the cost most (``t60``, ``n_points`` or ``duration_s``, as ``fields`` spells them, e.g.
    ``{"t60": "--t60"}``; default ``scene t60`` ...) and the estimate. A ``n_points`` spelt like
    ``duration_s`` follows the duration (``simulate --duration`` scales the trajectory)."""
    available = machine_memory()
    cost = costliest_scene(dist, n_mics)
    if available is None or cost.total <= available:
        return
    names = {**scene_fields("scene"), **(fields or {})}
    detail = (f"room impulse responses of {max_time(dist.t60[1]):.3g} s for {n_mics} microphones x {dist.n_points} "
              f"trajectory points, {dist.duration_s:.3g} s of audio")
    raise ConfigError(f"{_field(dist, cost, names)}: simulating a scene needs {_estimate(cost.total)} of memory "
                      f"({detail}), more than the {_gib(available)} of this machine")
