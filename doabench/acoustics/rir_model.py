"""The room impulse response model every engine shares: image sources plus a diffuse tail.

Details and rationale in docs/simulation.md, "Room impulse responses". The builtin engine
(:mod:`doabench.acoustics.rir`) renders the image sources itself; the other backends
(:mod:`doabench.acoustics.backends`) compute the early part their own way and share the rest:
the lengths (:func:`rir_layout`), the direct-path delays, the tail fitted to the early part and
the result's shape (:class:`RirParts`).

* **Early part, ``[0, Tdiff)``**: the image-source method of Allen & Berkley (1979) for a
  shoebox with six reflection coefficients. Every image within reach contributes
  ``prod(beta) / (4 pi d)`` at delay ``d / c``, band-limited by a Hann-windowed sinc centred on
  the arrival time; the window spans +-SINC_HALF = 16 samples (the width of pyroomacoustics'
  33-tap fractional delay), so an image touches 2 * SINC_HALF = 32 samples. No high-pass filter.
* **Diffuse tail, ``[Tdiff, Tmax)``**: Gaussian noise with a power envelope
  ``A**2 * exp(-ln(10**6) t / T60)`` (60 dB per T60), **one per microphone, shared by every
  point of a batch (trajectory)** (:func:`shared_tail`). ``A**2`` is fitted per (point, mic) to
  the energy of the image-source part in ``[Tdiff / 2, Tdiff)`` (the direct sound excluded) so
  the tail continues the ISM's energy envelope (:func:`tail_level`), and energy-averaged over
  the points. Why shared: the late field is diffuse, its decay and level hardly depend on the
  source position, and a position-independent tail lets a moving source's whole signal be
  convolved once per microphone with it while only the short early part (~Tdiff fs taps instead
  of ~Tmax fs) is convolved per trajectory segment (:class:`RirParts`,
  ``convolution.convolve_parts``). For one point (a static source) the result is the per-point
  model's; :func:`write_diffuse_tail_` keeps that model (independent per point) for comparisons.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from doabench.acoustics.room import Room
from doabench.geometry import SPEED_OF_SOUND

SINC_HALF = 16  # windowed-sinc half width in samples (pyroomacoustics frac_delay_length = 33)
_TAIL_FIT_MIN_SAMPLES = 32  # below this many usable ISM samples the tail level is theoretical
TAIL_MODEL = "shared: one diffuse tail per microphone for all trajectory points"  # provenance


@dataclass(frozen=True)
class ImageSet:
    """Image sources of a shoebox room, independent of the source position.

    Image ``i`` of a source at ``s`` sits at ``offset[i] + sign[i] * s`` and its amplitude factor
    is ``gain[i]`` (product of the reflection coefficients of the walls it reflects on, ``order[i]``
    reflections in all). Arrays: ``sign``, ``offset`` ``(I, 3)``; ``gain`` ``(I,)`` float64;
    ``order`` ``(I,)`` int64.
    """

    sign: np.ndarray
    offset: np.ndarray
    gain: np.ndarray
    order: np.ndarray

    def __len__(self) -> int:
        return int(self.gain.shape[0])


def enumerate_images(room: Room, horizon: float) -> ImageSet:
    """Every image that can be closer than ``horizon`` metres to some point of the room.

    Per axis of length L, image ``(u, l)`` (u in {0, 1}, l integer) has coordinate
    ``2 l L + (1 - 2u) x`` and reflects ``|l - u|`` times on the wall at 0 and ``|l|`` times on the
    wall at L (Allen & Berkley). Images whose distance from *any* pair of points in the room
    exceeds ``horizon`` are dropped, as are images with zero gain (walls with beta = 0).
    """
    beta = room.reflection_coefficients()
    axes = []
    for axis, length in enumerate(room.dims):
        n = int(math.ceil(horizon / (2.0 * length))) + 1
        l = np.repeat(np.arange(-n, n + 1), 2)
        u = np.tile(np.array([0, 1]), 2 * n + 1)
        sign = 1.0 - 2.0 * u
        offset = 2.0 * l * length
        k0, k1 = np.abs(l - u), np.abs(l)
        gain = np.power(beta[2 * axis], k0) * np.power(beta[2 * axis + 1], k1)
        lo = np.where(sign > 0, offset, offset - length)  # the image coordinate's range over
        hi = lo + length  # sources in [0, L], and the mic's range is [0, L] too
        lower = np.maximum(0.0, np.maximum(lo - length, -hi))
        keep = (lower <= horizon) & (gain > 0)
        axes.append((sign[keep], offset[keep], gain[keep], (k0 + k1)[keep], lower[keep]))
    (sx, ox, gx, kx, bx), (sy, oy, gy, ky, by), (sz, oz, gz, kz, bz) = axes
    ix: np.ndarray  # the index grids: 3-d from the meshgrid, then flat
    iy: np.ndarray
    iz: np.ndarray
    ix, iy, iz = np.meshgrid(np.arange(len(sx)), np.arange(len(sy)), np.arange(len(sz)), indexing="ij")
    ix, iy, iz = ix.ravel(), iy.ravel(), iz.ravel()
    keep = bx[ix] ** 2 + by[iy] ** 2 + bz[iz] ** 2 <= horizon**2
    ix, iy, iz = ix[keep], iy[keep], iz[keep]
    return ImageSet(
        sign=np.stack([sx[ix], sy[iy], sz[iz]], 1),
        offset=np.stack([ox[ix], oy[iy], oz[iz]], 1),
        gain=gx[ix] * gy[iy] * gz[iz],
        order=(kx[ix] + ky[iy] + kz[iz]).astype(np.int64),
    )


def direct_images() -> ImageSet:
    """Only the source itself (free field)."""
    return ImageSet(np.ones((1, 3)), np.zeros((1, 3)), np.ones(1), np.zeros(1, dtype=np.int64))


@dataclass(frozen=True)
class RirLayout:
    """Sample counts of one batch of RIRs: ``n_diff`` (tail start, Tdiff), ``n_early`` (end of the
    image-source part; Tdiff, or later when the direct sound itself arrives after Tdiff) and
    ``n_taps`` (total length, Tmax)."""

    n_diff: int
    n_early: int
    n_taps: int


def rir_layout(room: Room | None, max_direct_delay: float, fs: int) -> RirLayout:
    """Lengths for a batch whose longest direct path takes ``max_direct_delay`` samples."""
    direct_end = int(math.ceil(max_direct_delay)) + SINC_HALF + 2
    if room is None or room.t60 == 0:
        return RirLayout(0, direct_end, direct_end)
    n_diff = int(round(room.diffuse_start() * fs))
    n_early = max(n_diff, direct_end)
    return RirLayout(n_diff, n_early, max(int(round(room.max_time() * fs)), n_early))


def direct_delays(sources: torch.Tensor, mics: torch.Tensor, fs: int) -> torch.Tensor:
    """Direct-path delays ``(S, M)`` in samples; ``mics`` ``(M, 3)`` shared by every point or
    ``(S, M, 3)``, the microphones that hear point ``s`` (a moving array)."""
    if mics.dim() == 3:
        return (sources.double()[:, None] - mics.double()).norm(dim=-1) * (fs / SPEED_OF_SOUND)
    return torch.cdist(sources.double(), mics.double()) * (fs / SPEED_OF_SOUND)


def decay_rate(t60: float) -> float:
    """Energy decay rate in 1/s: power falls 60 dB (10**6) in ``t60`` seconds."""
    return math.log(1e6) / t60


def tail_level(
    early: torch.Tensor, room: Room, fs: int, layout: RirLayout, delays: torch.Tensor
) -> torch.Tensor:
    """``A**2`` ``(P, M)``: the tail's power envelope at t = 0 so that ``A**2 exp(-k t)`` matches
    the energy of ``early`` ``(P, M, n_early)`` over ``[Tdiff/2, Tdiff)``, skipping everything up
    to ``SINC_HALF + 1`` samples after the direct sound (``delays`` ``(P, M)`` samples).

    Where fewer than 32 samples are usable (the direct sound arrives at about Tdiff) the level is
    the diffuse-field expectation of the image-source model, ``c / (4 pi V fs)``: images fill
    space with density ``1 / V`` and each contributes ``(gain / (4 pi d))**2``.
    """
    k = decay_rate(room.t60)
    start, stop = layout.n_diff // 2, layout.n_diff
    width = stop - start
    # The usable samples are a suffix [first, stop) of the window (a masked sum, accumulated in
    # float64; 2.6x cheaper than the suffix sums it replaced).
    first = torch.floor(delays + SINC_HALF + 1).to(torch.int64) + 1  # (P, M), first usable sample
    skip = (first - start).clamp(0, width)  # window samples before it
    sq = early[..., start:stop].square()
    sq.masked_fill_(torch.arange(width, device=early.device) < skip[..., None], 0.0)
    energy = sq.sum(-1, dtype=torch.float64)
    n = torch.arange(start, stop + 1, device=early.device, dtype=torch.float64)
    env_tail = torch.exp(-k * n / fs).flip(0).cumsum(0).flip(0) - torch.exp(-k * n[-1] / fs)
    expected = env_tail[skip]
    theory = torch.full_like(energy, SPEED_OF_SOUND / (4 * math.pi * room.volume * fs))
    fitted = energy / expected.clamp_min(1e-300)
    return torch.where(width - skip >= _TAIL_FIT_MIN_SAMPLES, fitted, theory)


def draw_tail_noise(
    n_points: int, n_mics: int, layout: RirLayout, generator: torch.Generator, device: torch.device | None = None
) -> torch.Tensor:
    """Standard normal noise ``(S, M, n_taps - n_diff)`` float32, drawn on ``generator``'s device
    and returned on ``device`` (default: the generator's).

    Drawn in one call for the whole batch, so the tail of a given seed does not depend on how
    the engine chunks the points (nor on the backend that computed the early part). The engine
    itself draws ``S = 1`` (one shared tail, :func:`shared_tail`).
    """
    n = max(layout.n_taps - layout.n_diff, 0)
    noise = torch.randn(n_points, n_mics, n, generator=generator, device=generator.device, dtype=torch.float32)
    return noise if device is None else noise.to(device)


def shared_tail(
    levels: torch.Tensor | None, room: Room, fs: int, layout: RirLayout, generator: torch.Generator
) -> torch.Tensor | None:
    """The position-independent diffuse tail ``(M, n_taps - n_diff)`` float32, added to every
    point's RIR from sample ``n_diff`` on (None when T60 = 0 or there is no tail).

    ``levels`` ``(S, M)`` float64: the per-(point, mic) fitted levels of :func:`tail_level`; the
    tail of mic ``m`` has power envelope ``mean_s(levels[s, m]) exp(-k t)`` (the energy-average
    over the trajectory) and its own Gaussian noise, drawn here in one call (``(1, M, n)``, so a
    static source gets the same tail as a per-point engine would draw for it).

    Why one tail for the whole trajectory: the late field is diffuse, its statistics (decay rate,
    level within a fraction of a dB over a room) hardly depend on where the source is, while its
    fine structure is noise anyway. A shared tail lets :meth:`Simulator.simulate` convolve the
    whole signal once per microphone with it instead of once per trajectory point.
    """
    if levels is None or room.t60 == 0 or layout.n_taps <= layout.n_diff:
        return None
    noise = draw_tail_noise(1, levels.shape[1], layout, generator, levels.device)[0]
    n = torch.arange(layout.n_diff, layout.n_taps, device=noise.device, dtype=torch.float64)
    env = torch.exp(-0.5 * decay_rate(room.t60) * n / fs).to(torch.float32)  # amplitude
    noise.mul_(levels.to(noise.device).mean(0).sqrt().to(torch.float32)[:, None])
    return noise.mul_(env)


def write_diffuse_tail_(
    rirs: torch.Tensor,
    room: Room,
    fs: int,
    layout: RirLayout,
    delays: torch.Tensor,
    noise: torch.Tensor | None,
) -> torch.Tensor:
    """Complete RIRs in place with *independent* tails per (point, mic) and return ``rirs``
    (the previous engine's model; the backends now use :func:`shared_tail`, this stays for
    comparisons and tests).

    ``rirs`` ``(P, M, >= n_taps)`` float32 holds the image-source part in its first ``n_early``
    samples; samples ``[n_early, n_taps)`` are overwritten with the tail (zeros when T60 = 0):
    ``noise`` ``(P, M, n_taps - n_diff)`` (:func:`draw_tail_noise`, used up as scratch) shaped by
    the decaying envelope, added from ``n_diff`` on. ``delays`` ``(P, M)``: direct-path delays in
    samples (:func:`tail_level`).
    """
    if noise is None or room.t60 == 0 or layout.n_taps <= layout.n_diff:
        rirs[..., layout.n_early : layout.n_taps] = 0.0
        return rirs
    level = tail_level(rirs[..., : layout.n_early], room, fs, layout, delays)  # (P, M)
    n = torch.arange(layout.n_diff, layout.n_taps, device=rirs.device, dtype=torch.float64)
    env = torch.exp(-0.5 * decay_rate(room.t60) * n / fs).to(torch.float32)  # amplitude
    noise.mul_(level.sqrt().to(torch.float32)[..., None])
    overlap = layout.n_early - layout.n_diff  # > 0 only when the direct sound comes after Tdiff
    if overlap:
        rirs[..., layout.n_diff : layout.n_early] += noise[..., :overlap] * env[:overlap]
    torch.mul(noise[..., overlap:], env[overlap:], out=rirs[..., layout.n_early : layout.n_taps])
    return rirs


@dataclass(frozen=True)
class RirParts:
    """A batch of RIRs as an early part per point plus one shared tail.

    ``early`` ``(S, M, >= n_early)`` float32: the image-source part in samples ``[0, n_early)``,
    zeros after; ``tail`` ``(M, n_taps - n_diff)`` float32 or None: the diffuse tail shared by
    every point, starting at sample ``n_diff`` (overlapping the early part when the direct sound
    arrives after Tdiff). The RIR of point ``s`` is ``early[s]`` plus ``tail`` from ``n_diff``.
    """

    early: torch.Tensor
    tail: torch.Tensor | None
    layout: RirLayout

    def full(self, width: int | None = None) -> torch.Tensor:
        """The complete RIRs ``(S, M, width)`` (default ``n_taps``; zeros after ``n_taps``)."""
        lay = self.layout
        S, M, have = self.early.shape
        width = lay.n_taps if width is None else max(int(width), lay.n_taps)
        if have >= width:
            out = self.early[..., :width].clone()
        else:
            out = torch.zeros(S, M, width, dtype=torch.float32, device=self.early.device)
            out[..., : lay.n_early] = self.early[..., : lay.n_early]
        if self.tail is not None:
            out[..., lay.n_diff : lay.n_taps] += self.tail
        return out


def plan(room: Room | None, sources: torch.Tensor, mics: torch.Tensor, fs: int) -> tuple[RirLayout, torch.Tensor]:
    """The layout of a batch of RIRs and its direct-path delays ``(S, M)`` in samples."""
    delays = direct_delays(sources, mics, fs)
    return rir_layout(room, float(delays.max()) if delays.numel() else 0.0, fs), delays
