"""The builtin room impulse response engine: image sources plus a diffuse tail, in torch.

The model (images, lengths, the diffuse tail, :class:`~doabench.acoustics.rir_model.RirParts`) is
:mod:`doabench.acoustics.rir_model`, which every backend shares; this module renders it.

Speed: the sinc is not evaluated per image. The compiled kernel (:mod:`doabench.acoustics.native`,
CPU) tabulates its 128 phases (16 kB) and adds each image's amplitude times the nearest phase's
32 taps: rounding the arrival to 1/128 sample errs by at most 5.3e-3 of the peak tap. The torch
path (GPUs, no C compiler) accumulates the images with linear interpolation into an
OVERSAMPLE = 8 times finer time grid, and one strided convolution whose kernel holds every
windowed-sinc phase turns the fine grid into samples (2 scattered writes per image instead of
32; linear interpolation between 1/8-sample phases errs by at most 6.4e-3 of the peak tap). So
the two paths are two approximations of the same exact model, about 1e-2 of the peak apart
(tested); each is bitwise reproducible. The torch path's per-image work runs in cache-sized
slices, single-threaded on CPU (see :func:`~doabench.acoustics.compute.single_threaded`).
"""
from __future__ import annotations

import contextlib
import math

import numpy as np
import torch
import torch.nn.functional as F

from doabench.acoustics import native
from doabench.acoustics.compute import resolve_device, single_threaded, work_elements
from doabench.acoustics.rir_model import (
    SINC_HALF,
    ImageSet,
    RirLayout,
    RirParts,
    direct_delays,
    direct_images,
    enumerate_images,
    plan,
    rir_layout,
    shared_tail,
    tail_level,
)
from doabench.acoustics.room import Room
from doabench.geometry import SPEED_OF_SOUND

KERNEL_PHASES = 128  # the C kernel: arrival times rounded to 1/128 sample (nearest tabulated phase)
OVERSAMPLE = 8  # the torch path: a 1/8-sample grid, linear interpolation in between
_BLOCK = 16  # outputs per strided-convolution step (speed only; results do not depend on it)
_CHUNK_ELEMENTS = 4_000_000  # bounds the temporaries of one chunk of trajectory points
# Elements (mics x images) per step of the per-image work: the temporaries stay in cache (the
# work is memory-bound; DRAM-sized temporaries were 2x slower).
_SLICE_ELEMENTS = 98304
# On CUDA, cache-sized pieces leave the device launch-bound: a 20 s trajectory at T60 1.2 s has
# about 50 M (point, image, microphone) elements, 500 slices of about 15 kernels of a few
# microseconds each. There the sizes bound GPU memory instead (a few hundred MB of temporaries).
_CHUNK_ELEMENTS_CUDA = 1 << 26
_SLICE_ELEMENTS_CUDA = 1 << 23


# --------------------------------------------------------------------------------------------
# the windowed-sinc kernel


def accumulate_(buffer: torch.Tensor, index: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
    """``buffer.view(-1)[index] += values`` summing duplicates, deterministically.

    On CPU a 1-D ``scatter_add_`` runs serially in index order (and is the fastest of the
    accumulating ops there); on CUDA ``scatter_add_``/``index_add_`` use atomics (order varies)
    while ``index_put_(accumulate=True)`` sorts first, which keeps same-seed runs bitwise equal.
    """
    flat = buffer.view(-1)
    if flat.is_cuda:
        flat.index_put_((index,), values, accumulate=True)
    else:
        flat.scatter_add_(0, index, values)
    return buffer


def windowed_sinc(t: np.ndarray, half: int = SINC_HALF) -> np.ndarray:
    """Hann-windowed sinc at times ``t`` (samples, any shape); zero for ``|t| >= half``.

    The window is pyroomacoustics' (``np.hanning(2 half + 1)`` centred on the arrival), here
    centred on the arrival time itself rather than on the nearest sample."""
    t = np.asarray(t, dtype=np.float64)
    w = 0.5 * (1.0 + np.cos(np.pi * t / half))
    return np.where(np.abs(t) < half, np.sinc(t) * w, 0.0)


def _interleaved_kernel(half: int, over: int, block: int) -> np.ndarray:
    """Weights ``(block, 1, (block + 2 half + 1) over)`` of the strided convolution.

    The input is the fine grid (``over`` columns per sample) after ``(half + 1) over`` columns of
    left padding, so column ``t`` of a block's window holds impulses at time
    ``t / over - half - 1`` relative to the block start; output ``s`` is sample ``s`` of the block.
    """
    s = np.arange(block)[:, None, None]
    t = np.arange((block + 2 * half + 1) * over)[None, None, :]
    return windowed_sinc(s + half + 1 - t / over, half)


_KERNELS: dict[tuple, torch.Tensor] = {}


def _kernel(device: torch.device) -> torch.Tensor:
    key = (str(device), SINC_HALF, OVERSAMPLE, _BLOCK)
    if key not in _KERNELS:
        k = _interleaved_kernel(SINC_HALF, OVERSAMPLE, _BLOCK)
        _KERNELS[key] = torch.as_tensor(k, dtype=torch.float32, device=device)
    return _KERNELS[key]


_TAP_TABLES: list[np.ndarray] = []


def _tap_table() -> np.ndarray:
    """The C kernel's windowed-sinc phases ``(KERNEL_PHASES, 2 SINC_HALF)`` (:func:`native.tap_table`), built once."""
    if not _TAP_TABLES:
        _TAP_TABLES.append(native.tap_table(windowed_sinc, SINC_HALF, KERNEL_PHASES))
    return _TAP_TABLES[0]


def image_kernel(device: str | torch.device | None = None) -> str:
    """Which implementation :func:`render_images` uses on ``device``: ``"c"`` (the compiled
    kernel of :mod:`doabench.acoustics.native`, CPU only) or ``"torch"``."""
    return native.kernel_name() if resolve_device(device).type == "cpu" else "torch"


def _rows_contiguous(out: torch.Tensor) -> bool:
    """True when ``out`` ``(P, M, width)`` is a row-slice of a contiguous tensor (the kernel's layout)."""
    P, M, W = out.shape
    return out.stride() == (M * W, W, 1)


# --------------------------------------------------------------------------------------------
# the early (image-source) part


def render_images(
    images: ImageSet,
    sources: torch.Tensor,
    mics: torch.Tensor,
    fs: int,
    n_out: int,
    out: torch.Tensor | None = None,
    workspace: list | None = None,
) -> torch.Tensor:
    """Band-limited image-source responses, ``(P, M, n_out)`` float32 on the sources' device.

    ``sources`` ``(P, 3)`` and ``mics`` ``(M, 3)`` float tensors (room coordinates, metres), or
    ``mics`` ``(P, M, 3)``: the microphones that hear each point (a moving array). Images
    that cannot reach sample ``n_out`` are skipped. Memory grows with ``P``; callers chunk.
    ``out``: a contiguous ``(P, M, >= n_out)`` float32 tensor to write the samples into (its
    first ``n_out`` samples; returned). ``workspace``: a list holding a reusable scratch tensor
    (callers looping over chunks pass the same list; a fresh 30 MB allocation per chunk costs
    more in page faults than zeroing a reused one).
    """
    device = sources.device
    per_point = mics.dim() == 3
    P, M = sources.shape[0], mics.shape[-2]
    if out is None:
        out = torch.empty(P, M, n_out, dtype=torch.float32, device=device)
    if P == 0 or n_out == 0:
        return out
    half, over, block = SINC_HALF, OVERSAMPLE, _BLOCK
    to_samples = fs / SPEED_OF_SOUND

    # Coordinates relative to the array centre keep |p|^2 - 2 p.m + |m|^2 free of cancellation.
    # (A moving array: the centre of all its positions, so a radius that covers every pose.)
    centre = mics.to(torch.float64).reshape(-1, 3).mean(0)
    mic = (mics.to(torch.float64) - centre).to(torch.float32)
    src = sources.to(torch.float32)
    arr_radius = float(mic.norm(dim=-1).max())
    reach = (n_out + half) / to_samples + arr_radius
    lib = native.library() if device.type == "cpu" else None
    if lib is not None and _rows_contiguous(out):  # the compiled kernel (native.py): one fused pass
        native.render(lib, src.contiguous().numpy(), mic.contiguous().numpy(),
                      np.ascontiguousarray(images.sign, dtype=np.float32),
                      np.ascontiguousarray(images.offset - centre.numpy(), dtype=np.float32),
                      np.ascontiguousarray(images.gain / (4.0 * math.pi), dtype=np.float32),
                      reach * reach, to_samples * KERNEL_PHASES, _tap_table(), out.numpy(), n_out)
        return out[..., :n_out]
    sign = torch.as_tensor(images.sign, dtype=torch.float32, device=device)
    offset = torch.as_tensor(images.offset - centre.cpu().numpy(), dtype=torch.float32, device=device)
    gain = torch.as_tensor(images.gain / (4.0 * math.pi), dtype=torch.float32, device=device)

    # Keep (point, image) pairs whose image is within reach of the array's bounding sphere
    # (cheap (P, I) work that spares the (M, K) work below). Images up to 2 array radii beyond
    # the horizon for some mic are kept and land in spare buffer columns: cheaper than masking.
    rel = [torch.addcmul(offset[None, :, a], sign[None, :, a], src[:, a, None]) for a in range(3)]
    r2 = rel[0] * rel[0]
    r2.addcmul_(rel[1], rel[1]).addcmul_(rel[2], rel[2])
    flat = (r2.view(-1) <= reach * reach).nonzero().squeeze(1)  # (K,) into the (P, I) grid
    pos = torch.stack([r.view(-1).index_select(0, flat) for r in rel])  # (3, K) image positions
    pos_sq = r2.view(-1).index_select(0, flat)  # (index_select: 1.4x faster than [flat] here)
    p_idx = flat // len(images)
    amp = gain.index_select(0, flat - p_idx * len(images))
    del rel, r2, flat

    # Fine-grid buffer per (point, mic) row: (half + 1) * over columns of left padding for the
    # convolution, then the grid; n_blocks is rounded up to cover the spare columns.
    spare = int(math.ceil(2 * arr_radius * to_samples)) + 2
    n_blocks = -(-(n_out + spare) // block)
    width = (n_blocks * block + 2 * half + 1) * over
    size = P * M * width + 1  # +1: the w1 write of the last column
    if workspace is not None and workspace and workspace[0].numel() >= size:
        buf = workspace[0][:size].zero_()
    else:
        buf = torch.zeros(size, dtype=torch.float32, device=device)
        if workspace is not None:
            workspace[:] = [buf]
    index_dtype = torch.int32 if size < 2**31 else torch.int64
    row_start = (p_idx * (M * width) + (half + 1) * over).to(index_dtype)  # (K,) (point, mic 0)
    mic_start = (torch.arange(M, device=device)[:, None] * width).to(index_dtype)  # (M, 1)
    mic_sq = None if per_point else (mic * mic).sum(1, keepdim=True)
    index_buf = torch.empty(M * max(1, work_elements(device, _SLICE_ELEMENTS, _SLICE_ELEMENTS_CUDA) // M),
                            dtype=torch.int64, device=device)

    # Slices of images small enough that the (M, slice) temporaries stay in cache; the work is
    # memory-bound, and DRAM-sized temporaries made it 2-3x slower.
    n_slice = max(1, work_elements(device, _SLICE_ELEMENTS, _SLICE_ELEMENTS_CUDA) // M)
    serial = single_threaded() if device.type == "cpu" else contextlib.nullcontext()
    with serial:  # slices are cache-sized: threads only add hand-off cost
        for k0 in range(0, pos.shape[1], n_slice):
            k1 = min(pos.shape[1], k0 + n_slice)
            # distances (M, k) as |p|^2 - 2 p.m + |m|^2 (M x k layout: consecutive writes stay
            # in one (point, mic) row)
            if per_point:  # each image's own point's microphones: (k, M, 3) -> (M, k) distances
                near = mic.index_select(0, p_idx[k0:k1])
                dist = (pos[:, k0:k1].T[:, None, :] - near).square_().sum(-1).T.contiguous()
            else:
                assert mic_sq is not None, "computed whenever the points share their microphones"
                dist = mic_sq + pos_sq[None, k0:k1]
                for a in range(3):
                    dist.addcmul_(mic[:, a, None], pos[None, a, k0:k1], value=-2.0)
            dist.clamp_(min=1e-12).sqrt_()
            w0 = amp[k0:k1] / dist
            t = dist.mul_(to_samples * over)  # arrival on the fine grid, >= 0
            q = t.to(index_dtype)  # floor (t >= 0); float -> int32 is 10x cheaper than -> int64
            frac = t.frac_()  # = t - q exactly (t >= 0), without converting q back to float
            w1 = w0 * frac
            w0.sub_(w1)
            index = index_buf[: M * (k1 - k0)].view(M, k1 - k0)  # int64 straight from the adds
            torch.add(q, row_start[k0:k1], out=index).add_(mic_start)
            index = index.view(-1)
            accumulate_(buf[:-1], index, w0.view(-1))
            accumulate_(buf[1:], index, w1.view(-1))

    conv = F.conv1d(buf[:-1].view(P * M, 1, width), _kernel(device), stride=block * over)
    del buf
    # conv is (rows, sample-in-block, block); copy it transposed straight into `out`
    rows = out.view(P * M, out.shape[-1])
    full = n_out // block
    rows[:, : full * block].view(P * M, full, block).copy_(conv[..., :full].transpose(1, 2))
    rest = n_out - full * block
    if rest:
        rows[:, full * block : n_out] = conv[:, :rest, full]
    return out[..., :n_out]


# --------------------------------------------------------------------------------------------
# the whole engine


def _points_per_chunk(
    room: Room | None, n_mics: int, n_images: int, layout: RirLayout, fs: int, n_out: int | None = None,
    device: torch.device = torch.device("cpu"),
) -> int:
    """Points per chunk so that one chunk's largest temporaries stay near _CHUNK_ELEMENTS
    (_CHUNK_ELEMENTS_CUDA off the CPU; ``n_out``: samples per output row, default ``n_taps``)."""
    reach = (layout.n_early + SINC_HALF) / fs * SPEED_OF_SOUND
    heard = n_images if room is None else min(n_images, 4.2 * reach**3 / room.volume + 1)
    per_point = max(
        n_images,  # (P, I) pruning distances
        n_mics * heard,  # (M, K) per-image work
        n_mics * OVERSAMPLE * (layout.n_early + 2 * SINC_HALF + 2 * _BLOCK + 8),  # the torch path's fine grid
        n_mics * (layout.n_taps if n_out is None else n_out),  # output
    )
    return max(1, int(work_elements(device, _CHUNK_ELEMENTS, _CHUNK_ELEMENTS_CUDA) // per_point))


def _mics_of(mics: torch.Tensor, p0: int, p1: int) -> torch.Tensor:
    """The microphones of points ``[p0, p1)``: all of a shared ``(M, 3)`` array, or that slice of
    per-point ``(S, M, 3)`` positions."""
    return mics[p0:p1] if mics.dim() == 3 else mics


def image_source_parts(
    room: Room,
    sources: torch.Tensor,
    mics: torch.Tensor,
    fs: int,
    generator: torch.Generator,
    width: int | None = None,
) -> RirParts:
    """Early parts ``(S, M, width)`` and the shared tail (:class:`RirParts`) from ``sources``
    ``(S, 3)`` to ``mics`` ``(M, 3)`` (tensors on the device to compute on, room coordinates,
    already validated).

    ``width`` (>= n_early, default n_early): width of the early tensor, zeros after ``n_early``,
    e.g. an FFT length, which spares the FFT a padded copy. Points are processed in chunks to
    bound memory; the per-(point, mic) tail levels are fitted chunk by chunk and averaged at the
    end, and the tail noise is drawn once, so equal inputs and seed give equal outputs whatever
    the chunking.
    """
    layout, delays = plan(room, sources, mics, fs)
    horizon_m = (layout.n_early + SINC_HALF) / fs * SPEED_OF_SOUND
    images = enumerate_images(room, horizon_m) if room.t60 > 0 else direct_images()
    S, M = sources.shape[0], mics.shape[-2]
    width = layout.n_early if width is None else max(int(width), layout.n_early)
    early = torch.empty(S, M, width, dtype=torch.float32, device=sources.device)
    fit = room.t60 > 0 and layout.n_taps > layout.n_diff
    levels = torch.empty(S, M, dtype=torch.float64, device=sources.device) if fit else None
    step = _points_per_chunk(room, M, len(images), layout, fs, width, sources.device)
    scratch: list = []
    for p0 in range(0, S, step):
        p1 = min(S, p0 + step)
        chunk = render_images(images, sources[p0:p1], _mics_of(mics, p0, p1), fs, layout.n_early, out=early[p0:p1],
                              workspace=scratch)
        if levels is not None:
            levels[p0:p1] = tail_level(chunk, room, fs, layout, delays[p0:p1])
    if width > layout.n_early:
        early[..., layout.n_early :] = 0.0
    return RirParts(early, shared_tail(levels, room, fs, layout, generator), layout)


def image_source_rirs(
    room: Room,
    sources: torch.Tensor,
    mics: torch.Tensor,
    fs: int,
    generator: torch.Generator,
    width: int | None = None,
) -> torch.Tensor:
    """Complete RIRs ``(S, M, n_taps)`` float32 (``(S, M, width)`` zero-padded when ``width`` >
    n_taps): :func:`image_source_parts` with the shared tail added to every point."""
    return image_source_parts(room, sources, mics, fs, generator).full(width)


def direct_rirs(sources: torch.Tensor, mics: torch.Tensor, fs: int) -> torch.Tensor:
    """Free-field direct-path responses ``(S, M, n_taps)`` float32: ``1 / (4 pi r)`` at delay
    ``r / c`` with the same windowed sinc as the image-source part."""
    delays = direct_delays(sources, mics, fs)
    layout = rir_layout(None, float(delays.max()) if delays.numel() else 0.0, fs)
    images = direct_images()
    S, M = sources.shape[0], mics.shape[-2]
    out = torch.empty(S, M, layout.n_taps, dtype=torch.float32, device=sources.device)
    step = _points_per_chunk(None, M, 1, layout, fs, device=sources.device)
    scratch: list = []
    for p0 in range(0, S, step):
        p1 = min(S, p0 + step)
        render_images(images, sources[p0:p1], _mics_of(mics, p0, p1), fs, layout.n_taps, out=out[p0:p1],
                      workspace=scratch)
    return out
