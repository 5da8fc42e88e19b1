"""The moving-source convolution every simulator backend shares.

A moving source is simulated the way gpuRIR's ``simulateTrajectory`` does: the signal is cut into
``S`` consecutive segments (:func:`doabench.acoustics.trajectories.segment_bounds`), segment ``i``
is convolved with the RIRs of trajectory point ``i`` and the results are overlap-added
(:func:`convolve_trajectory`); with RIRs given as early parts plus one shared diffuse tail
(:class:`~doabench.acoustics.rir_model.RirParts`) the tail is convolved once with the whole signal
(:func:`convolve_parts`).
"""
from __future__ import annotations

import functools
import math

import numpy as np
import torch
from scipy import fft as scipy_fft
from scipy.fft import next_fast_len

from doabench.acoustics import compute
from doabench.acoustics import rir_model
from doabench.acoustics.trajectories import segment_bounds

# Spectra held at once by the FFT convolutions, (points, mics, nfft) or (mics, blocks, nfft): about
# 2 MB, so each chunk's transform, product and overlap-add stay in the L2 cache (8M-element
# chunks were about a third slower for the early part; docs/performance.md, "early conv").
_OLA_CHUNK_ELEMENTS = 500_000
_OLA_CHUNK_ELEMENTS_CUDA = 1 << 26  # on CUDA: fewer, larger transforms (compute.work_elements)


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
    step = max(1, compute.work_elements(device, _OLA_CHUNK_ELEMENTS, _OLA_CHUNK_ELEMENTS_CUDA) // (M * nfft))
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
    of :class:`~doabench.acoustics.rir_model.RirParts`, which starts at sample ``start``). Since the
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
    step = max(1, compute.work_elements(device, _OLA_CHUNK_ELEMENTS, _OLA_CHUNK_ELEMENTS_CUDA) // (n_blocks * nfft))
    for m0 in range(0, M, step):
        m1 = min(M, m0 + step)
        y = _irfft(spec_x[None] * spec_h[m0:m1, None], nfft)  # (mics, blocks, nfft)
        for k in range(n_hops):
            a, b = k * block, min((k + 1) * block, nfft)
            acc[m0:m1, k : k + n_blocks, : b - a] += y[..., a:b]
    out[:, start:] += acc.view(M, -1)[:, :n_out]
    return out


def convolve_parts(parts: rir_model.RirParts, signal: torch.Tensor) -> torch.Tensor:
    """Moving-source convolution ``(M, L)`` float32 with RIRs given as early parts plus a shared
    tail: :func:`convolve_trajectory` of the early parts (short FFTs, ~Tdiff fs) plus one long
    convolution of the whole signal with the tail (:func:`add_tail_convolution_`). Equals
    ``convolve_trajectory(parts.full(), signal)`` to float32 rounding."""
    lay = parts.layout
    out = convolve_trajectory(parts.early, signal, lay.n_early)
    if parts.tail is not None:
        add_tail_convolution_(out, signal.to(out.device), parts.tail, lay.n_diff)
    return out
