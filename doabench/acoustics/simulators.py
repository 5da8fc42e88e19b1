"""Room simulators: one interface, three backends, one trajectory convolution.

* ``builtin`` (default): doabench's torch image-source engine (:mod:`doabench.acoustics.rir`),
  CPU or CUDA.
* ``pyroomacoustics``: the same model through ``pyroomacoustics.ShoeBox`` (its image sources and
  fractional delays, our diffuse tail); the trusted reference and fallback.
* ``gpurir``: a thin wrapper of gpuRIR, the library the Cross3D paper used, when it is importable.

Every backend returns RIRs ``(S, M, n_taps)`` for ``S`` source points and ``M`` microphones, and
simulates a moving source the way gpuRIR's ``simulateTrajectory`` does: the signal is cut into
``S`` consecutive segments (:func:`segment_bounds`), segment ``i`` is convolved with the RIRs of
point ``i`` and the results are overlap-added.
"""
from __future__ import annotations

import contextlib
import functools
import importlib.util
import math
from typing import Protocol, runtime_checkable

import numpy as np
import torch
from scipy import fft as scipy_fft
from scipy.fft import next_fast_len

from doabench.acoustics import rir as engine
from doabench.acoustics.room import Room, check_inside
from doabench.errors import ConfigError, DependencyError, InputError, NotFoundError

_MIN_SOURCE_MIC_DISTANCE = 1e-3  # metres; 1 / (4 pi r) blows up at the microphone
# Spectra held at once by the FFT convolutions, (points, mics, nfft) or (mics, blocks, nfft): about
# 2 MB, so each chunk's transform, product and overlap-add stay in the L2 cache (8M-element
# chunks were about a third slower for the early part; docs/performance.md, "early conv").
_OLA_CHUNK_ELEMENTS = 500_000
_OLA_CHUNK_ELEMENTS_CUDA = 1 << 26  # on CUDA: fewer, larger transforms (engine.work_elements)


@runtime_checkable
class Simulator(Protocol):
    """What every backend provides. Positions are room coordinates in metres."""

    name: str

    def versions(self) -> dict[str, str]:
        """Backend, library versions and pinned settings, for provenance."""

    def rirs(
        self, room: Room, sources: np.ndarray, mics: np.ndarray, fs: int, *, seed=None
    ) -> np.ndarray:
        """RIRs ``(S, M, n_taps)`` float32 from ``sources`` ``(S, 3)`` to ``mics`` ``(M, 3)``."""

    def simulate(
        self, room: Room, sources: np.ndarray, mics: np.ndarray, signal: np.ndarray, fs: int, *, seed=None
    ) -> np.ndarray:
        """Microphone signals ``(M, L)`` float32 of ``signal`` ``(L,)`` moving along ``sources``
        ``(S, 3)`` (S == 1: static); ``mics`` ``(M, 3)``, or ``(S, M, 3)`` for an array that moves
        with the trajectory's segments."""


# --------------------------------------------------------------------------------------------
# validation


def _check_fs(fs) -> int:
    if isinstance(fs, bool) or not isinstance(fs, (int, np.integer)) or fs <= 0:
        raise ConfigError(f"sample rate must be a positive integer number of Hz, got {fs!r}")
    return int(fs)


def _points(room: Room | None, points, what: str) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim == 1 and p.shape == (3,):
        p = p[None]
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] == 0:
        raise ConfigError(f"{what} positions must have shape (N, 3) with N >= 1, got {np.shape(points)}")
    if room is None:
        if not np.all(np.isfinite(p)):
            i = int(np.argmax(~np.all(np.isfinite(p), axis=1)))
            raise ConfigError(f"{what} {i + 1} is not finite")
        return p
    return check_inside(room, p, what)


def prepare_geometry(room: Room | None, sources, mics, fs) -> tuple[np.ndarray, np.ndarray, int]:
    """Validate and return ``sources (S, 3)``, ``mics`` float64 and ``fs``.

    ``mics`` is ``(M, 3)`` (a static array) or ``(S, M, 3)``: the microphones that hear trajectory
    point ``s`` (a moving array; a single source point is then repeated to ``S`` points)."""
    if room is not None and not isinstance(room, Room):
        raise ConfigError(f"room must be a doabench.acoustics.room.Room, got {type(room).__name__}")
    fs = _check_fs(fs)
    src = _points(room, sources, "source point")
    raw = np.asarray(mics, dtype=np.float64)
    if raw.ndim == 3:  # a moving array
        if raw.shape[2] != 3 or raw.shape[1] == 0 or (len(src) != 1 and raw.shape[0] != len(src)):
            raise ConfigError(f"per-point microphone positions must have shape (S, M, 3) with S = {len(src)} "
                              f"source points, got {raw.shape}")
        mic = _points(room, raw.reshape(-1, 3), "array microphone").reshape(raw.shape)
        if len(src) == 1:
            src = np.repeat(src, raw.shape[0], axis=0)
        d = np.linalg.norm(src[:, None] - mic, axis=-1)
        if d.min() < _MIN_SOURCE_MIC_DISTANCE:
            i, j = np.unravel_index(int(np.argmin(d)), d.shape)
            raise ConfigError(f"source point {i + 1} is at array microphone {j + 1} (closer than 1 mm)")
        return src, mic, fs
    mic = _points(room, mics, "array microphone")
    d = np.linalg.norm(src[:, None] - mic[None], axis=-1)
    if d.min() < _MIN_SOURCE_MIC_DISTANCE:
        i, j = np.unravel_index(int(np.argmin(d)), d.shape)
        raise ConfigError(f"source point {i + 1} is at array microphone {j + 1} (closer than 1 mm)")
    return src, mic, fs


def _signal(signal) -> np.ndarray:
    x = np.asarray(signal)
    if x.ndim != 1 or x.size == 0:
        raise InputError(f"source signal must be 1-D and non-empty, got shape {x.shape}")
    if not np.issubdtype(x.dtype, np.number) or not np.all(np.isfinite(x)):
        raise InputError("source signal contains NaN, infinite or non-numeric values")
    return x.astype(np.float32, copy=False)


# --------------------------------------------------------------------------------------------
# trajectory convolution (shared by every backend)


def segment_bounds(n_samples: int, n_points: int) -> np.ndarray:
    """Sample boundaries ``(n_points + 1,)`` int64: segment ``i`` is
    ``[b[i], b[i + 1])`` with ``b[i] = floor(i * n_samples / n_points)`` (lengths differ by at
    most one sample)."""
    return (np.arange(n_points + 1, dtype=np.int64) * n_samples) // n_points


@functools.lru_cache(maxsize=None)
def cpu_fft_backend() -> str:
    """The FFT library for CPU tensors: ``"torch"`` (MKL) on Intel CPUs, ``"scipy"`` (pocketfft)
    elsewhere. Measured on 12-600 batched float32 transforms of 4,800 and 331,776 points, one
    thread: on AMD EPYC pocketfft was about twice as fast as torch's MKL build, on Intel Xeon
    (AVX-512) MKL was 1.6x faster than pocketfft (docs/performance.md). Fixed per machine, so a
    seeded simulation stays bitwise reproducible there."""
    if not torch.backends.mkl.is_available():
        return "scipy"
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            intel = any(line.startswith("vendor_id") and "GenuineIntel" in line for line in f)
    except OSError:
        intel = False
    return "torch" if intel else "scipy"


def _rfft(x: torch.Tensor, n: int) -> torch.Tensor:
    if x.device.type == "cpu" and cpu_fft_backend() == "scipy":
        return torch.from_numpy(scipy_fft.rfft(x.numpy(), n, workers=torch.get_num_threads()))
    return torch.fft.rfft(x, n)


def _irfft(x: torch.Tensor, n: int) -> torch.Tensor:
    if x.device.type == "cpu" and cpu_fft_backend() == "scipy":
        return torch.from_numpy(scipy_fft.irfft(x.numpy(), n, workers=torch.get_num_threads()))
    return torch.fft.irfft(x, n)


def trajectory_fft_size(n_samples: int, n_points: int, n_taps: int) -> int:
    """FFT length :func:`convolve_trajectory` uses for these sizes."""
    bounds = segment_bounds(n_samples, n_points)
    hop = n_samples // n_points
    if hop == 0:
        return next_fast_len(n_taps, real=True)
    frame = int((bounds[:-1] - np.arange(n_points) * hop + np.diff(bounds)).max())
    return next_fast_len(frame + n_taps - 1, real=True)


def convolve_trajectory(rirs: torch.Tensor, signal: torch.Tensor, n_taps: int | None = None) -> torch.Tensor:
    """Moving-source convolution, ``(M, L)`` float32 on ``rirs``' device.

    ``rirs`` ``(S, M, N)``, ``signal`` ``(L,)``. ``n_taps``: the RIRs' true length when ``rirs``
    is zero-padded beyond it (to :func:`trajectory_fft_size`, which saves a padded copy). Segment ``i`` of the signal (:func:`segment_bounds`)
    is FFT-convolved with ``rirs[i]`` and added at its start sample; the output keeps the first
    ``L`` samples. Batched over points and mics, chunked over points to bound memory.

    Segment ``i`` starts at ``b[i] = i * hop + shift[i]`` with ``hop = L // S`` and
    ``0 <= shift[i] < S``; placing it ``shift[i]`` samples into its FFT frame puts every frame on
    the uniform ``hop`` grid, so the overlap-add is a few dense block additions (no index
    tensors, deterministic on every device).
    """
    S, M, width = rirs.shape
    N = width if n_taps is None else int(n_taps)
    L = signal.shape[-1]
    device = rirs.device
    signal = signal.to(device=device, dtype=torch.float32)
    bounds = segment_bounds(L, S)
    hop = L // S
    if hop == 0:  # more points than samples: only the points that own a sample matter
        keep = np.flatnonzero(np.diff(bounds) > 0)
        return convolve_trajectory(rirs[torch.as_tensor(keep, device=device)], signal, N)
    shift = bounds[:-1] - np.arange(S) * hop
    frame = int((shift + np.diff(bounds)).max())  # frame samples holding signal
    nfft = trajectory_fft_size(L, S, N)
    col = torch.arange(frame, device=device)[None] - torch.as_tensor(shift, device=device)[:, None]
    seg_len = torch.as_tensor(np.diff(bounds), device=device)[:, None]
    src_idx = torch.as_tensor(bounds[:-1], device=device)[:, None] + col
    frames = torch.where(
        (col >= 0) & (col < seg_len), signal[src_idx.clamp(0, L - 1)], torch.zeros((), device=device)
    )  # (S, frame): segment i at offset shift[i]
    n_hops = -(-nfft // hop)  # output hops one frame touches
    out = torch.zeros(M, S + n_hops, hop, dtype=torch.float32, device=device)
    step = max(1, engine.work_elements(device, _OLA_CHUNK_ELEMENTS, _OLA_CHUNK_ELEMENTS_CUDA) // (M * nfft))
    for p0 in range(0, S, step):
        p1 = min(S, p0 + step)
        h = rirs[p0:p1] if width == nfft else rirs[p0:p1, :, :N]
        spec = _rfft(h.to(torch.float32), nfft)
        spec *= _rfft(frames[p0:p1], nfft)[:, None]
        y = _irfft(spec, nfft).transpose(0, 1)  # (M, P, nfft) view
        for k in range(n_hops):  # a handful of block adds, each over all points and mics
            a, b = k * hop, min((k + 1) * hop, nfft)
            out[:, p0 + k : p1 + k, : b - a] += y[..., a:b]
    return out.view(M, -1)[:, :L]


def tail_block_size(n_tail: int, n_out: int) -> int:
    """Signal samples per block of :func:`add_tail_convolution_`: the power of two at or above
    twice the tail length, at least 8192 (and at most the output length). In one-off timings on
    our Intel Xeon (12 mics x 20 s, one thread) blocks of 2-4 tail lengths were fastest: the
    330,000-point transforms of the whole signal do not fit in the cache, smaller blocks pay for
    their overlap (the effect on a trajectory: docs/performance.md, "tail conv")."""
    block = max(8192, 1 << max(0, math.ceil(math.log2(max(1, 2 * n_tail)))))
    return max(1, min(block, n_out))


def add_tail_convolution_(out: torch.Tensor, signal: torch.Tensor, tail: torch.Tensor, start: int) -> torch.Tensor:
    """``out[m, start + k] += (signal * tail[m])[k]`` for ``k < L - start``; returns ``out``.

    ``out`` ``(M, L)``, ``signal`` ``(L,)``, ``tail`` ``(M, N)`` float32 (the shared diffuse tail
    of :class:`~doabench.acoustics.rir.RirParts`, which starts at sample ``start``). Since the
    tail is the same for every trajectory point, the sum over segments of ``segment * tail`` is
    ``signal * tail``: one convolution of the whole signal per microphone, done as a blocked
    overlap-add (:func:`tail_block_size`) whose block spectra of the signal are shared by every
    microphone. Equals the direct convolution to float32 rounding.
    """
    M, L = out.shape
    n_out = L - int(start)
    n_tail = tail.shape[-1]
    if n_out <= 0 or n_tail == 0:
        return out
    device = tail.device
    block = tail_block_size(n_tail, n_out)
    nfft = next_fast_len(block + n_tail - 1, real=True)
    n_blocks = -(-n_out // block)
    x = torch.zeros(n_blocks * block, dtype=torch.float32, device=device)
    x[:n_out] = signal[:n_out].to(device=device, dtype=torch.float32)
    spec_x = _rfft(x.view(n_blocks, block), nfft)  # (blocks, nfft // 2 + 1), shared by every mic
    spec_h = _rfft(tail.to(torch.float32), nfft)  # (M, nfft // 2 + 1)
    n_hops = -(-nfft // block)  # blocks one block's output touches
    acc = torch.zeros(M, n_blocks + n_hops, block, dtype=torch.float32, device=device)
    step = max(1, engine.work_elements(device, _OLA_CHUNK_ELEMENTS, _OLA_CHUNK_ELEMENTS_CUDA) // (n_blocks * nfft))
    for m0 in range(0, M, step):
        m1 = min(M, m0 + step)
        y = _irfft(spec_x[None] * spec_h[m0:m1, None], nfft)  # (mics, blocks, nfft)
        for k in range(n_hops):
            a, b = k * block, min((k + 1) * block, nfft)
            acc[m0:m1, k : k + n_blocks, : b - a] += y[..., a:b]
    out[:, start:] += acc.view(M, -1)[:, :n_out]
    return out


def convolve_parts(parts: engine.RirParts, signal: torch.Tensor) -> torch.Tensor:
    """Moving-source convolution ``(M, L)`` float32 with RIRs given as early parts plus a shared
    tail: :func:`convolve_trajectory` of the early parts (short FFTs, ~Tdiff fs) plus one long
    convolution of the whole signal with the tail (:func:`add_tail_convolution_`). Equals
    ``convolve_trajectory(parts.full(), signal)`` to float32 rounding."""
    lay = parts.layout
    out = convolve_trajectory(parts.early, signal, lay.n_early)
    if parts.tail is not None:
        add_tail_convolution_(out, signal.to(out.device), parts.tail, lay.n_diff)
    return out


def direct_path(
    room: Room | None,
    sources: np.ndarray,
    mics: np.ndarray,
    signal: np.ndarray,
    fs: int,
    *,
    device: str | torch.device | None = None,
) -> np.ndarray:
    """Free-field direct-path signals ``(M, L)`` float32: amplitude ``1 / (4 pi r)``, delay
    ``r / c`` by the builtin engine's windowed sinc, same segmenting and overlap-add as
    :meth:`Simulator.simulate`. ``room`` (optional) only validates the positions. Used to set an
    SNR relative to the direct-path power without a second simulation."""
    src, mic, fs = prepare_geometry(room, sources, mics, fs)
    x = _signal(signal)
    dev = engine.resolve_device(device)
    with _threads(dev):
        h = engine.direct_rirs(torch.tensor(src, device=dev), torch.tensor(mic, device=dev), fs)
        return convolve_trajectory(h, torch.as_tensor(x, device=dev)).cpu().numpy()


# --------------------------------------------------------------------------------------------
# backends


def _threads(device: torch.device):
    """Single-threaded torch on CPU for the duration of a simulation.

    One trajectory is many medium-sized ops: two threads gained little on an idle 2-core machine,
    and on a loaded one the thread-pool hand-offs made it 5-20x slower. To use more cores,
    simulate several trajectories in parallel processes (e.g. data-loader workers).
    """
    return engine.single_threaded() if device.type == "cpu" else contextlib.nullcontext()


class _TorchBackend:
    """Shared ``rirs``/``simulate`` plumbing. Subclasses implement ``rirs_parts`` (early parts
    plus a shared tail, :class:`~doabench.acoustics.rir.RirParts`; the fast path) or only
    ``rirs_tensor`` (complete RIRs, convolved per trajectory point)."""

    name = "?"
    device: torch.device

    def rirs_parts(
        self, room: Room, sources: np.ndarray, mics: np.ndarray, fs: int, generator, width: int | None = None
    ) -> engine.RirParts | None:
        return None

    def rirs_tensor(self, room: Room, sources: np.ndarray, mics: np.ndarray, fs: int, generator) -> torch.Tensor:
        parts = self.rirs_parts(room, sources, mics, fs, generator)
        if parts is None:
            raise NotImplementedError
        return parts.full()

    def rirs(self, room: Room, sources, mics, fs: int, *, seed=None) -> np.ndarray:
        """RIRs ``(S, M, n_taps)`` float32, ``n_taps = round(Tmax fs)`` (direct path only when
        T60 = 0). ``seed`` (int or torch.Generator) fixes the diffuse-tail noise."""
        src, mic, fs = prepare_geometry(room, sources, mics, fs)
        gen = engine.make_generator(seed, self.device)
        with _threads(self.device):
            return self.rirs_tensor(room, src, mic, fs, gen).cpu().numpy()

    def simulate(self, room: Room, sources, mics, signal, fs: int, *, seed=None) -> np.ndarray:
        """Signals ``(M, L)`` float32 of ``signal`` ``(L,)`` moving along ``sources`` ``(S, 3)``;
        equals :func:`convolve_trajectory` of :meth:`rirs` with the same seed (to float32
        rounding where the backend has a shared tail)."""
        src, mic, fs = prepare_geometry(room, sources, mics, fs)
        x = _signal(signal)
        gen = engine.make_generator(seed, self.device)
        xt = torch.as_tensor(x, device=self.device)
        with _threads(self.device):
            layout, _ = engine.plan(room, torch.tensor(src), torch.tensor(mic), fs)
            nfft = trajectory_fft_size(len(x), len(src), layout.n_early)
            parts = self.rirs_parts(room, src, mic, fs, gen, width=nfft)  # zero-padded: no copy in the FFT
            if parts is not None:
                return convolve_parts(parts, xt).cpu().numpy()
            h = self.rirs_tensor(room, src, mic, fs, gen)
            return convolve_trajectory(h, xt).cpu().numpy()


class BuiltinSimulator(_TorchBackend):
    """doabench's torch image-source engine (see :mod:`doabench.acoustics.rir`)."""

    name = "builtin"

    def __init__(self, device: str | torch.device | None = None) -> None:
        self.device = engine.resolve_device(device)

    def versions(self) -> dict[str, str]:
        from doabench._version import __version__

        return {
            "backend": self.name,
            "doabench": __version__,
            "torch": torch.__version__,
            "device": str(self.device),
            "sinc": f"hann-windowed over +-{engine.SINC_HALF} samples; arrival at the nearest 1/"
                    f"{engine.KERNEL_PHASES} sample (image_kernel c) or linear between 1/{engine.OVERSAMPLE}-sample "
                    "phases (image_kernel torch)",
            "hpf": "none",
            "tail": engine.TAIL_MODEL,
            "image_kernel": engine.image_kernel(self.device),
            "fft": cpu_fft_backend() if self.device.type == "cpu" else "torch",
        }

    def rirs_parts(
        self, room: Room, sources: np.ndarray, mics: np.ndarray, fs: int, generator, width: int | None = None
    ) -> engine.RirParts:
        src = torch.tensor(sources, device=self.device)
        mic = torch.tensor(mics, device=self.device)
        return engine.image_source_parts(room, src, mic, fs, generator, width)


_PRA_WALLS = ("west", "east", "south", "north", "floor", "ceiling")  # = x0, x1, y0, y1, z0, z1


class PyroomacousticsSimulator(_TorchBackend):
    """The same model through pyroomacoustics' ShoeBox image sources.

    Pinned settings (restored afterwards): ``frac_delay_length = 33`` (the builtin's sinc width, +-16),
    ``sinc_lut_granularity = 20``, ``rir_hpf_enable = False``, ``c = 343``; no air absorption, no
    ray tracing, no randomised ISM; ``max_order`` = the highest reflection order among the images
    that reach Tdiff. Its RIRs are shifted back by its ``frac_delay_length // 2`` global delay and
    scaled by ``1 / (4 pi)`` (pyroomacoustics uses ``1 / r``), cut at Tdiff, and the builtin's
    shared diffuse tail (:func:`doabench.acoustics.rir.shared_tail`, fitted to these early parts)
    is added from there, so builtin and pyroomacoustics differ only in their image sources.
    """

    name = "pyroomacoustics"
    SOURCES_PER_ROOM = 8  # bounds pyroomacoustics' image arrays

    def __init__(self, device: str | torch.device | None = None) -> None:
        if importlib.util.find_spec("pyroomacoustics") is None:
            raise DependencyError("pyroomacoustics is not installed: pip install pyroomacoustics==0.10.1")
        self.device = engine.resolve_device(device)

    def settings(self) -> dict:
        from doabench.geometry import SPEED_OF_SOUND

        return {
            "frac_delay_length": 2 * engine.SINC_HALF + 1,
            "sinc_lut_granularity": 20,
            "rir_hpf_enable": False,
            "c": SPEED_OF_SOUND,
        }

    def versions(self) -> dict[str, str]:
        import pyroomacoustics as pra

        out = {"backend": self.name, "pyroomacoustics": pra.__version__, "torch": torch.__version__,
               "tail": engine.TAIL_MODEL}
        out.update({k: str(v) for k, v in self.settings().items()})
        return out

    @contextlib.contextmanager
    def _constants(self):
        import pyroomacoustics as pra

        old = {k: pra.constants.get(k) for k in self.settings()}
        try:
            for k, v in self.settings().items():
                pra.constants.set(k, v)
            yield pra
        finally:
            for k, v in old.items():
                pra.constants.set(k, v)

    def max_order(self, room: Room, layout: engine.RirLayout, fs: int) -> int:
        """Reflection order that includes every image arriving before the end of the ISM part."""
        if room.t60 == 0:
            return 0
        from doabench.geometry import SPEED_OF_SOUND

        horizon = (layout.n_early + engine.SINC_HALF) / fs * SPEED_OF_SOUND
        return int(engine.enumerate_images(room, horizon).order.max())

    def early_part(self, room: Room, sources: np.ndarray, mics: np.ndarray, fs: int, layout) -> np.ndarray:
        """pyroomacoustics' image-source responses ``(S, M, n_early)`` float32 (our conventions)."""
        S, M = len(sources), mics.shape[-2]
        early = np.zeros((S, M, layout.n_early), dtype=np.float32)
        beta = room.reflection_coefficients()
        order = self.max_order(room, layout, fs)
        # A moving array (mics (S, M, 3)): one room per point, each with that point's microphones.
        per_room = 1 if mics.ndim == 3 else self.SOURCES_PER_ROOM
        with self._constants() as pra:
            shift = pra.constants.get("frac_delay_length") // 2
            materials = {w: pra.Material(energy_absorption=float(1 - b**2)) for w, b in zip(_PRA_WALLS, beta)}
            for s0 in range(0, S, per_room):  # pyroomacoustics' API is per source
                chunk = sources[s0 : s0 + per_room]
                room_mics = mics[s0] if mics.ndim == 3 else mics
                shoebox = pra.ShoeBox(
                    list(room.dims), fs=fs, materials=materials, max_order=order,
                    air_absorption=False, ray_tracing=False, use_rand_ism=False,
                )
                for p in chunk:
                    shoebox.add_source(list(p))
                shoebox.add_microphone_array(np.asarray(room_mics, dtype=np.float64).T)
                shoebox.compute_rir()
                for m in range(M):
                    for k in range(len(chunk)):
                        h = np.asarray(shoebox.rir[m][k][shift : shift + layout.n_early])
                        early[s0 + k, m, : len(h)] = h / (4 * math.pi)
        return early

    def rirs_parts(
        self, room: Room, sources: np.ndarray, mics: np.ndarray, fs: int, generator, width: int | None = None
    ) -> engine.RirParts:
        src = torch.tensor(sources, device=self.device)
        mic = torch.tensor(mics, device=self.device)
        delays = engine.direct_delays(src, mic, fs)
        layout = engine.rir_layout(room, float(delays.max()), fs)
        width = layout.n_early if width is None else max(int(width), layout.n_early)
        early = torch.zeros(len(sources), mics.shape[-2], width, dtype=torch.float32, device=self.device)
        early[..., : layout.n_early] = torch.as_tensor(self.early_part(room, sources, mics, fs, layout), device=self.device)
        levels = None
        if room.t60 > 0 and layout.n_taps > layout.n_diff:
            levels = engine.tail_level(early[..., : layout.n_early], room, fs, layout, delays)
        return engine.RirParts(early, engine.shared_tail(levels, room, fs, layout, generator), layout)


GPURIR_INSTALL = (
    "gpuRIR is not installed: it is not on PyPI and needs an NVIDIA GPU with the CUDA toolkit; "
    "install it from its GitHub repository with "
    "`pip install https://github.com/DavidDiazGuerra/gpuRIR/zipball/master`"
)


class GpuRIRSimulator(_TorchBackend):
    """Thin wrapper of gpuRIR's public API (``beta_SabineEstimation``, ``att2t_SabineEstimator``,
    ``t2n``, ``simulateRIR`` with ``Tdiff``/``Tmax``). Amplitudes and tail are gpuRIR's own; its
    tail noise is drawn on the GPU by gpuRIR and ``seed`` has no effect on it."""

    name = "gpurir"

    def __init__(self, device: str | torch.device | None = None) -> None:
        try:
            import gpuRIR
        except ImportError:
            raise DependencyError(GPURIR_INSTALL) from None
        self._gpurir = gpuRIR
        self.device = engine.resolve_device(device)

    def versions(self) -> dict[str, str]:
        return {
            "backend": self.name,
            "gpuRIR": str(getattr(self._gpurir, "__version__", "unknown")),
            "torch": torch.__version__,
        }

    def rirs_tensor(self, room: Room, sources: np.ndarray, mics: np.ndarray, fs: int, generator) -> torch.Tensor:
        g = self._gpurir
        if np.ndim(mics) == 3:
            raise ConfigError("the gpurir backend simulates static arrays only; use builtin or pyroomacoustics "
                              "for a moving array")
        dims = np.asarray(room.dims)
        if room.t60 == 0:
            beta = np.zeros(6)
            n_img = [1, 1, 1]
            delays = engine.direct_delays(torch.as_tensor(sources), torch.as_tensor(mics), fs)
            t_diff = None
            t_max = engine.rir_layout(None, float(delays.max()), fs).n_taps / fs
        else:
            beta = g.beta_SabineEstimation(dims, room.t60, np.asarray(room.abs_weights))
            t_diff = g.att2t_SabineEstimator(12, room.t60)
            t_max = g.att2t_SabineEstimator(40, room.t60)
            n_img = g.t2n(t_diff, dims)
        kwargs = {} if t_diff is None else {"Tdiff": t_diff}
        h = g.simulateRIR(dims, beta, np.asarray(sources), np.asarray(mics), n_img, t_max, fs, **kwargs)
        return torch.as_tensor(np.asarray(h, dtype=np.float32), device=self.device)


_BACKENDS = {
    "builtin": BuiltinSimulator,
    "pyroomacoustics": PyroomacousticsSimulator,
    "gpurir": GpuRIRSimulator,
}


def simulator_names() -> list[str]:
    return list(_BACKENDS)


def get_simulator(name: str = "builtin", device: str | torch.device | None = None) -> Simulator:
    """A backend by name: ``builtin`` (default; torch on ``device``, CPU when None),
    ``pyroomacoustics`` or ``gpurir`` (DependencyError when gpuRIR is not importable)."""
    key = str(name).lower()
    if key not in _BACKENDS:
        raise NotFoundError(f"unknown simulator {name!r}: use one of {', '.join(_BACKENDS)}")
    try:
        dev = engine.resolve_device(device)
    except (RuntimeError, TypeError):
        raise ConfigError(f"unknown torch device {device!r}") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise DependencyError(f"device {device!r} requested but torch has no CUDA device here")
    return _BACKENDS[key](dev)
