"""Feature extraction as pure torch functions: STFT frames, GCC-PHAT, SRP-PHAT maps, spectrograms.

Conventions (see docs/features.md for the long version):

* Audio is ``(batch, n_mics, samples)``; frames follow :mod:`doabench.framing` (complete windows
  only, frame ``t`` covers samples ``[t * hop, t * hop + K)``).
* Window: **periodic** Hann, ``w[n] = 0.5 - 0.5 cos(2 pi n / K)`` (``torch.hann_window``'s default).
* Spectra ``X`` are ``(batch, frames, n_mics, K // 2 + 1)`` complex64.
* PHAT is applied per microphone, ``W_n = X_n / sqrt(|X_n|^2 + eps^2)`` (the paper's
  ``G_n = 1 / |X_n|``), so the cross-spectrum of a pair is ``W_n W_m^*`` and a silent (all-zero)
  frame gives zeros.
* ``R_nm(tau) = (1/K) sum over all K bins of W_n W_m^* e^{j w_k tau}`` (``irfft``), which peaks at
  ``tau = tau_n - tau_m``: the delay of mic ``n`` relative to mic ``m``.
* Plane-wave delays in samples: ``tau_n(u) = -(r_n . u) fs / c`` (a mic closer to the source hears
  it earlier). An SRP map is ``sum over pairs n < m of R_nm(tau_n(u) - tau_m(u))``.

Everything is vectorised; the only Python loops are over memory blocks (chunks of frames, bins or
grid points) and over GCC lags, never over individual frames, pairs or grid points.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np
import torch
from numpy.typing import ArrayLike

from doabench.errors import ConfigError, InputError
from doabench.features.configs import DELAY_MODES
from doabench.features.kinds import DelayMode
from doabench.geometry import SPEED_OF_SOUND, grid_unit_vectors

PHAT_EPS = 1e-12
#: Microphone pairs ``(n_pairs, 2)``: ``MicArray.pairs``, a long tensor or nested sequences.
PairsLike = np.ndarray | torch.Tensor | Sequence[Sequence[int]]

# Working-set bounds for the blocked computations. Small blocks keep intermediates in cache, which
# matters more than GEMM size on memory-bound CPUs.
_GCC_BLOCK_BYTES = 4 << 20  # whitened time signals of a block of frames
_EXACT_TILE_BYTES = 256 << 10  # one bin's (frames x grid) beamformer output
_EXACT_BLOCK_BYTES = 2 << 20  # a few bins of it
# Up to this many non-negative lags, GCCs come from one GEMM per lag (lag_gram); beyond it a
# full-length irfft per pair is cheaper.
_GRAM_MAX_LAGS = 64


# --------------------------------------------------------------------------------------------
# Frames and spectra
# --------------------------------------------------------------------------------------------
def hann_window(window: int, device: torch.device | str | None = None, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """Periodic Hann window of ``window`` samples, shape ``(window,)``."""
    return torch.hann_window(window, periodic=True, device=device, dtype=dtype)


def n_bins(window: int) -> int:
    """Number of rfft bins of a ``window``-sample frame: ``window // 2 + 1``."""
    return window // 2 + 1


def rfft_weights(window: int, device: torch.device | str | None = None, dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """Multiplicity of each rfft bin in the full K-bin spectrum, shape ``(window // 2 + 1,)``.

    1 for DC and (even K) Nyquist, 2 for the others: sums over the full spectrum of a real
    signal's Hermitian quantities become weighted sums over the rfft bins.
    """
    a = torch.full((n_bins(window),), 2.0, device=device, dtype=dtype)
    a[0] = 1.0
    if window % 2 == 0:
        a[-1] = 1.0
    return a


def stft_frames(x: torch.Tensor, window: int, hop: int) -> torch.Tensor:
    """Hann-windowed rfft of every complete frame.

    ``x``: ``(batch, n_mics, samples)`` real -> ``(batch, frames, n_mics, window // 2 + 1)``
    complex64 (complex128 for float64 input). ``frames = 1 + (samples - window) // hop``.
    """
    if x.ndim != 3:
        raise InputError(f"audio must be (batch, n_mics, samples), got shape {tuple(x.shape)}")
    if x.shape[-1] < window:
        raise InputError(f"recording has {x.shape[-1]} samples, shorter than one {window}-sample window")
    if not x.is_floating_point():
        x = x.float()
    from doabench.framing import frame_signal

    return windowed_rfft(frame_signal(x, window, hop).transpose(1, 2))


def windowed_rfft(frames: torch.Tensor) -> torch.Tensor:
    """Hann-windowed rfft of frames ``(..., K)`` (any strides) -> ``(..., K // 2 + 1)`` complex."""
    K = frames.shape[-1]
    # Writing the windowed frames into a fresh contiguous buffer makes the spectra contiguous in
    # the order the caller gave (elementwise ops would otherwise keep the input's strides).
    buf = torch.empty(frames.shape, dtype=frames.dtype, device=frames.device)
    torch.mul(frames, hann_window(K, frames.device, frames.dtype), out=buf)
    spectra: torch.Tensor = torch.fft.rfft(buf, dim=-1)
    return spectra


def phat(X: torch.Tensor, eps: float = PHAT_EPS) -> torch.Tensor:
    """PHAT-whitened spectra ``X / sqrt(|X|^2 + eps^2)``, same shape as ``X`` (zero bins stay zero)."""
    # rsqrt of the squared magnitude on real views is ~4x faster than X / (X.abs() + eps).
    inv = torch.addcmul(X.real.square(), X.imag, X.imag).add_(eps * eps).rsqrt_()
    return torch.view_as_complex(torch.view_as_real(X) * inv.unsqueeze(-1))


# --------------------------------------------------------------------------------------------
# GCC-PHAT
# --------------------------------------------------------------------------------------------
def _as_pairs(pairs: PairsLike, n_mics: int, device: torch.device) -> torch.Tensor:
    p = torch.as_tensor(np.asarray(pairs), dtype=torch.long, device=device)
    if p.ndim != 2 or p.shape[1] != 2:
        raise ConfigError(f"pairs must be (n_pairs, 2), got shape {tuple(p.shape)}")
    if p.numel() and (p.min() < 0 or p.max() >= n_mics):
        raise ConfigError(f"pairs refer to microphones outside 0..{n_mics - 1}")
    return p


def gram_lag_index(pairs: PairsLike, n_mics: int, max_lag: int) -> torch.Tensor:
    """Where each GCC value sits in the lag-Gram tensor of :func:`lag_gram`.

    Returns ``(n_pairs, 2 * max_lag + 1)`` long indices into a ``(max_lag + 1, n_mics, n_mics)``
    tensor flattened: lag ``l >= 0`` of pair ``(n, m)`` is ``G[l, n, m]``; lag ``-l`` is
    ``G[l, m, n]`` (``R_nm(-l) = R_mn(l)``).
    """
    p = torch.as_tensor(np.asarray(pairs), dtype=torch.long)
    lags = torch.arange(-max_lag, max_lag + 1)
    first = torch.where(lags[None] >= 0, p[:, :1], p[:, 1:])  # (P, L)
    second = torch.where(lags[None] >= 0, p[:, 1:], p[:, :1])
    return lags.abs()[None] * n_mics * n_mics + first * n_mics + second


def lag_gram(W: torch.Tensor, window: int, max_lag: int) -> torch.Tensor:
    """Circular cross-correlations of all mic pairs at lags ``0..max_lag``, via the time domain.

    ``W``: ``(frames, n_mics, n_bins)`` whitened spectra -> ``(frames, max_lag + 1, n_mics,
    n_mics)`` with ``[t, l, n, m] = sum_s w_n((s + l) mod K) w_m(s) = R_nm(l)``, where
    ``w = irfft(W)``. Each lag is one batched GEMM reading shifted *views* of the whitened
    signals, so no per-pair cross-spectrum is ever materialised: that memory traffic, not the
    arithmetic, is what bounds the frequency-domain formulation on CPU.
    """
    T, M, _ = W.shape
    ext = torch.empty((T, M, window + max_lag), dtype=W.real.dtype, device=W.device)
    torch.fft.irfft(W, n=window, dim=-1, out=ext[..., :window])
    ext[..., window:] = ext[..., :max_lag]  # circular wrap for the positive shifts
    w_t = ext[..., :window].transpose(1, 2)  # (T, K, M)
    out = torch.empty((T, max_lag + 1, M, M), dtype=ext.dtype, device=W.device)
    for lag in range(max_lag + 1):  # lags, not frames or pairs: a handful of large GEMMs
        torch.bmm(ext[..., lag : lag + window], w_t, out=out[:, lag])
    return out


def gcc_from_phat(
    W: torch.Tensor, pairs: torch.Tensor, max_lag: int, window: int, index: torch.Tensor | None = None
) -> torch.Tensor:
    """GCC-PHAT from already whitened spectra.

    ``W``: ``(batch, frames, n_mics, n_bins)`` complex; ``pairs``: ``(n_pairs, 2)`` long ->
    ``(batch, frames, n_pairs, 2 * max_lag + 1)`` real, lags ``-max_lag..max_lag``.
    ``index``: :func:`gram_lag_index` for these pairs (built if missing).
    """
    B, T, M, F = W.shape
    P = pairs.shape[0]
    n_lags = 2 * max_lag + 1
    out = torch.empty((B, T, P, n_lags), dtype=W.real.dtype, device=W.device)
    if B * T == 0 or P == 0:
        return out
    Wf = W.reshape(B * T, M, F)
    flat_out = out.view(B * T, P * n_lags)
    if max_lag + 1 <= _GRAM_MAX_LAGS:
        if index is None:
            index = gram_lag_index(pairs.cpu(), M, max_lag)
        index = index.to(W.device).reshape(-1)
        block = max(1, _GCC_BLOCK_BYTES // (M * (window + max_lag) * W.real.element_size()))
        for s in range(0, B * T, block):  # blocks keep the whitened signals in cache
            gram = lag_gram(Wf[s : s + block], window, max_lag)
            torch.index_select(gram.reshape(gram.shape[0], -1), 1, index, out=flat_out[s : s + block])
        return out
    # Many lags (large arrays): one irfft per pair and frame is cheaper than a GEMM per lag.
    i, j = pairs[:, 0].to(W.device), pairs[:, 1].to(W.device)
    block = max(1, _GCC_BLOCK_BYTES // (P * window * W.real.element_size()))
    for s in range(0, B * T, block):
        w = Wf[s : s + block]
        r = torch.fft.irfft(w[:, i] * w[:, j].conj(), n=window, dim=-1)
        flat_out[s : s + block] = torch.cat([r[..., window - max_lag :], r[..., : max_lag + 1]], dim=-1).reshape(r.shape[0], -1)
    return out


def gcc_phat(
    X: torch.Tensor, pairs: PairsLike, max_lag: int, eps: float = PHAT_EPS, window: int | None = None
) -> torch.Tensor:
    """GCC-PHAT of microphone pairs.

    ``X``: ``(batch, frames, n_mics, n_bins)`` complex spectra (:func:`stft_frames`);
    ``pairs``: ``(n_pairs, 2)`` mic indices (``MicArray.pairs``); ``max_lag`` from
    ``MicArray.max_lag(fs)``. Returns ``(batch, frames, n_pairs, 2 * max_lag + 1)`` real for lags
    ``-max_lag..max_lag``: ``R_nm(tau) = irfft(W_n W_m^*)[tau]``, peaking at ``tau_n - tau_m``.
    ``window`` is the frame length K (default ``2 * (n_bins - 1)``, i.e. even K).
    """
    window = _window_of(X, window)
    if max_lag < 0 or 2 * max_lag + 1 > window:
        raise ConfigError(f"max_lag {max_lag} outside 0..{(window - 1) // 2} for a {window}-sample window")
    p = _as_pairs(pairs, X.shape[-2], X.device)
    return gcc_from_phat(phat(X, eps), p, int(max_lag), window)


def _window_of(X: torch.Tensor, window: int | None) -> int:
    if X.ndim != 4 or not X.is_complex():
        raise InputError(f"spectra must be complex (batch, frames, n_mics, n_bins), got {tuple(X.shape)} {X.dtype}")
    F = X.shape[-1]
    if window is None:
        window = 2 * (F - 1)
    if n_bins(window) != F:
        raise ConfigError(f"window {window} does not match {F} frequency bins")
    return int(window)


# --------------------------------------------------------------------------------------------
# SRP-PHAT
# --------------------------------------------------------------------------------------------
def plane_wave_delays(positions: ArrayLike, directions: ArrayLike, fs: float, c: float = SPEED_OF_SOUND) -> np.ndarray:
    """Arrival delays in samples of a plane wave from ``directions``.

    ``positions``: ``(n_mics, 3)`` metres; ``directions``: ``(..., 3)`` unit vectors towards the
    source. Returns ``(..., n_mics)`` float64, ``tau_n = -(r_n . u) fs / c``.
    """
    pos = np.asarray(positions, dtype=np.float64)
    u = np.asarray(directions, dtype=np.float64)
    delays: np.ndarray = -(u @ pos.T) * (fs / c)
    return delays


def grid_delays(positions: ArrayLike, n_theta: int, n_phi: int, fs: float, planar: bool = False, c: float = SPEED_OF_SOUND) -> np.ndarray:
    """Delays of every grid direction, ``(n_mics, n_theta * n_phi)`` float64 samples (row-major grid)."""
    u = grid_unit_vectors(n_theta, n_phi, planar).reshape(-1, 3)
    delays: np.ndarray = plane_wave_delays(positions, u, fs, c).T
    return delays


def nearest_lag_index(tau: np.ndarray, pairs: np.ndarray, max_lag: int) -> np.ndarray:
    """Flat lookup indices for nearest-sample SRP.

    ``tau``: ``(n_mics, n_grid)`` delays in samples; returns ``(n_grid, n_pairs)`` int64 indices
    into a GCC flattened over ``(n_pairs, 2 * max_lag + 1)``: ``p * n_lags + round(dtau) + max_lag``.
    Rounding is numpy's (half to even).
    """
    pairs = np.asarray(pairs)
    dtau = tau[pairs[:, 0]] - tau[pairs[:, 1]]  # (P, G)
    lag = np.rint(dtau).astype(np.int64)
    if lag.size and np.abs(lag).max() > max_lag:
        raise ConfigError(f"grid delays need lags up to {np.abs(lag).max()}, more than max_lag {max_lag}")
    n_lags = 2 * max_lag + 1
    index: np.ndarray = (np.arange(len(pairs))[:, None] * n_lags + lag + max_lag).T.copy()
    return index


def srp_from_gcc(gcc: torch.Tensor, index: torch.Tensor, n_theta: int, n_phi: int) -> torch.Tensor:
    """Nearest-sample SRP maps from GCCs.

    ``gcc``: ``(batch, frames, n_pairs, n_lags)``; ``index``: ``(n_grid, n_pairs)`` from
    :func:`nearest_lag_index`. Returns raw maps ``(batch, frames, n_theta, n_phi)``.
    """
    B, T, P, L = gcc.shape
    if B * T == 1:
        # One frame (streaming): embedding_bag on a one-column table is 20-40x slower than a
        # gather of the (n_grid, n_pairs) values (64x128: 19 against 0.5 ms; docs/performance.md).
        picked = gcc.reshape(P * L).index_select(0, index.to(gcc.device).reshape(-1))
        return picked.reshape(index.shape).sum(dim=1).reshape(1, 1, n_theta, n_phi)
    table = gcc.reshape(B * T, P * L).t().contiguous()  # (P*L, B*T)
    # embedding_bag sums, for each grid point, the P table rows it names: a gather + sum over
    # pairs with no (grid x pairs x frames) intermediate.
    maps = torch.nn.functional.embedding_bag(index.to(gcc.device), table, mode="sum")  # (G, B*T)
    return maps.t().reshape(B, T, n_theta, n_phi)


def steering(tau: torch.Tensor, window: int, bins: slice = slice(None)) -> torch.Tensor:
    """Phase-alignment factors ``E = e^{j w_f tau_n(g)}`` as real GEMM operands.

    ``tau``: ``(n_mics, n_grid)`` float64 samples -> ``(n_bins, 2 * n_mics, n_grid)`` float32,
    ``[cos(w_f tau); sin(w_f tau)]`` stacked on the mic axis, for the rfft bins selected by
    ``bins``. With :func:`_beamformer_rows` it gives ``Re Y`` and ``Im Y`` of ``Y(g) = sum_n W_n
    E_n(g)`` in one real GEMM, several times faster than a complex one on CPU.
    """
    M, G = tau.shape
    k = torch.arange(n_bins(window), dtype=torch.float64, device=tau.device)[bins]
    # Phases are formed in float64 and reduced to (-2 pi, 2 pi) before the float32 cast, so the
    # float32 sin/cos see a small argument (error ~5e-7 rad) however large w * tau gets.
    cycles = (k / window)[:, None, None] * tau.to(torch.float64)[None]  # (F, M, G)
    phase = torch.frac_(cycles).mul_(2 * math.pi).to(torch.float32)
    table = torch.empty((len(k), 2 * M, G), dtype=torch.float32, device=tau.device)
    torch.cos(phase, out=table[:, :M])
    torch.sin(phase, out=table[:, M:])
    return table


def _beamformer_rows(W: torch.Tensor) -> torch.Tensor:
    """``(BT, n_mics, F)`` complex -> ``(F, 2 BT, 2 n_mics)`` real rows ``[Wr, -Wi]``, ``[Wi, Wr]``
    per frame, so that ``rows @ [cos; sin]`` is ``Re Y``, ``Im Y`` interleaved per frame."""
    Wr, Wi = W.real, W.imag
    rows = torch.stack([torch.cat([Wr, -Wi], dim=1), torch.cat([Wi, Wr], dim=1)], dim=1)  # (BT, 2, 2M, F)
    return rows.reshape(W.shape[0] * 2, 2 * W.shape[1], W.shape[2]).permute(2, 0, 1).contiguous()


def srp_exact_from_phat(
    W: torch.Tensor,
    tau: torch.Tensor,
    window: int,
    n_theta: int,
    n_phi: int,
    steer: torch.Tensor | None = None,
) -> torch.Tensor:
    """Exact fractional-delay SRP maps from whitened spectra.

    ``W``: ``(batch, frames, n_mics, n_bins)`` complex; ``tau``: ``(n_mics, n_grid)`` samples;
    ``steer``: optional precomputed :func:`steering` table for all bins and grid points (else
    generated block by block). Returns ``(batch, frames, n_theta, n_phi)`` equal to
    ``sum_{n<m} R_nm(tau_n - tau_m)`` with ``R(tau) = (1/K)[Phi_0 + 2 sum_k Re(Phi_k e^{j w_k tau})
    + Re(Phi_{K/2} e^{j pi tau})]``.

    Computed as a PHAT beamformer ``Y_f(g) = sum_n W_n(f) e^{j w_f tau_n(g)}``: ``|Y|^2`` is the
    sum over all ordered pairs, so removing the diagonal ``sum_n |W_n|^2`` and halving leaves the
    unique-pair sum; the rfft weights turn the bin sum into the full-spectrum sum.
    """
    B, T, M, F = W.shape
    G = tau.shape[1]
    BT = B * T
    dtype = W.real.dtype
    # Both sums over the spectrum are ~2 K M (1e5 for NAO at K = 4096) while their difference,
    # the map, is O(M): accumulating them in float32 would cost ~1e-5 of absolute accuracy.
    out = torch.zeros((BT, G), dtype=torch.float64, device=W.device)
    if BT == 0:
        return out.to(dtype).reshape(B, T, n_theta, n_phi)
    a = rfft_weights(window, W.device, dtype)
    Wf = W.reshape(BT, M, F)
    rows = _beamformer_rows(Wf)  # (F, 2 BT, 2M)
    diag = rfft_weights(window, W.device) @ (Wf.real.square() + Wf.imag.square()).sum(1).t().double()  # (BT,)
    # Blocks: a (frames x grid) output tile small enough for cache per bin, and a few bins per
    # GEMM, accumulated at once, so the (bins x frames x grid) beamformer output never exists.
    t_block = min(BT, 256)
    g_block = max(8, min(G, _EXACT_TILE_BYTES // (t_block * 8)))
    # At most 16 bins are summed in float32 (inside torch.mv); block sums accumulate in float64.
    f_block = max(1, min(F, 16, _EXACT_BLOCK_BYTES // (t_block * g_block * 8)))
    tau = tau.to(W.device)
    for g0 in range(0, G, g_block):
        g1 = min(G, g0 + g_block)
        for f0 in range(0, F, f_block):
            f1 = min(F, f0 + f_block)
            if steer is not None:
                E = steer[f0:f1, :, g0:g1]
            else:
                E = steering(tau[:, g0:g1], window, slice(f0, f1))
            E = E.to(dtype)
            for t0 in range(0, BT, t_block):
                t1 = min(BT, t0 + t_block)
                Y = torch.bmm(rows[f0:f1, 2 * t0 : 2 * t1], E).square_()  # (fb, 2 tb, gb)
                power = torch.mv(Y.view(f1 - f0, -1).t(), a[f0:f1]).view(t1 - t0, 2, g1 - g0).sum(1)
                out[t0:t1, g0:g1] += power
    out = ((out - diag[:, None]) / (2 * window)).to(dtype)
    return out.reshape(B, T, n_theta, n_phi)


def srp_phat(
    X: torch.Tensor,
    positions: ArrayLike,
    n_theta: int,
    n_phi: int,
    fs: float,
    mode: DelayMode = "nearest",
    planar: bool = False,
    c: float = SPEED_OF_SOUND,
    eps: float = PHAT_EPS,
    window: int | None = None,
) -> torch.Tensor:
    """Raw SRP-PHAT maps on the equiangular grid (:func:`doabench.geometry.grid_angles`).

    ``X``: ``(batch, frames, n_mics, n_bins)`` complex spectra; ``positions``: ``(n_mics, 3)``.
    Returns ``(batch, frames, n_theta, n_phi)``: ``sum over pairs n < m of R_nm(tau_n - tau_m)``.
    ``mode="nearest"`` rounds each pair delay to the nearest sample (the paper);
    ``mode="exact"`` evaluates the fractional delays exactly in the frequency domain.
    """
    window = _window_of(X, window)
    pos = np.asarray(positions, dtype=np.float64)
    if pos.ndim != 2 or pos.shape != (X.shape[-2], 3):
        raise ConfigError(f"positions must be ({X.shape[-2]}, 3) for {X.shape[-2]} mics, got {pos.shape}")
    _check_resolution(n_theta, n_phi)
    tau = grid_delays(pos, n_theta, n_phi, fs, planar, c)
    W = phat(X, eps)
    if mode == "exact":
        return srp_exact_from_phat(W, torch.from_numpy(tau), window, n_theta, n_phi)
    if mode != "nearest":
        raise ConfigError(f"unknown delay mode {mode!r}: use one of {', '.join(DELAY_MODES)}")
    pairs = np.stack(np.triu_indices(len(pos), 1), axis=1).astype(np.int64)  # MicArray.pairs order
    d_max = float(np.linalg.norm(pos[:, None] - pos[None], axis=-1).max())
    max_lag = int(np.ceil(d_max / c * fs))
    if 2 * max_lag + 1 > window:
        raise ConfigError(f"the array needs GCC lags up to {max_lag} samples, too many for a {window}-sample window")
    index = torch.from_numpy(nearest_lag_index(tau, pairs, max_lag))
    gcc = gcc_from_phat(W, torch.from_numpy(pairs).to(X.device), max_lag, window)
    return srp_from_gcc(gcc, index, n_theta, n_phi)


def _check_resolution(n_theta: int, n_phi: int) -> None:
    from doabench.geometry import check_grid

    check_grid(int(n_theta), int(n_phi))


# --------------------------------------------------------------------------------------------
# Map post-processing
# --------------------------------------------------------------------------------------------
def normalize_maps(maps: torch.Tensor) -> torch.Tensor:
    """Subtract each map's mean, then divide by its (new) maximum (the paper), ``(..., n_theta, n_phi)``.

    A flat map (maximum after centring <= 1e-6 of its largest magnitude, e.g. an all-zero
    silent frame) becomes all zeros instead of dividing by ~0.
    """
    centred = maps - maps.mean(dim=(-2, -1), keepdim=True)
    peak = centred.amax(dim=(-2, -1), keepdim=True)
    scale = maps.abs().amax(dim=(-2, -1), keepdim=True)
    flat = peak <= 1e-6 * scale
    return torch.where(flat, torch.zeros_like(centred), centred / torch.where(flat, torch.ones_like(peak), peak))


def map_argmax(maps: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Row (elevation) and column (azimuth) index of each map's maximum, each ``(...)`` long."""
    n_phi = maps.shape[-1]
    flat = maps.flatten(-2).argmax(-1)
    return flat // n_phi, flat % n_phi


def map_maxima(maps: torch.Tensor, planar: bool = False) -> torch.Tensor:
    """Normalised position of each map's maximum, ``(..., n_theta, n_phi)`` -> ``(..., 2)``.

    Channel 0: ``theta_hat / theta_max`` (``theta_max`` = pi, or pi/2 for planar grids), i.e.
    ``row / (n_theta - 1)``; channel 1: ``(phi_hat + pi) / (2 pi)`` = ``col / n_phi``. Both in
    ``[0, 1]``. ``planar`` does not change the numbers (both are fractions of the grid span) and is
    accepted for symmetry with :func:`map_argmax_directions`.
    """
    n_theta, n_phi = maps.shape[-2:]
    row, col = map_argmax(maps)
    return torch.stack([row.to(maps.dtype) / (n_theta - 1), col.to(maps.dtype) / n_phi], dim=-1)


def map_argmax_directions(maps: torch.Tensor, planar: bool = False) -> torch.Tensor:
    """Unit vectors ``(..., 3)`` of each map's maximum on the grid."""
    n_theta, n_phi = maps.shape[-2:]
    u = torch.as_tensor(grid_unit_vectors(n_theta, n_phi, planar), dtype=maps.dtype, device=maps.device)
    row, col = map_argmax(maps)
    return u[row, col]


# --------------------------------------------------------------------------------------------
# Spectrogram features and silent frames
# --------------------------------------------------------------------------------------------
#: The phase channels :func:`spectrogram_features` can give: each microphone's own phase, or its
#: phase relative to the first microphone's (the interchannel phase difference).
SPECTROGRAM_PHASES = ("absolute", "relative")


def spectrogram_features(X: torch.Tensor, phase: str = "absolute") -> torch.Tensor:
    """Magnitude and phase channels, ``(batch, frames, n_mics, n_bins)`` -> ``(batch, frames,
    2 * n_mics, n_bins - 1)`` float.

    Channels ``0..M-1``: each mic's magnitude divided by its maximum over frequency in that frame
    (an all-zero spectrum stays zero); channels ``M..2M-1``: phase / pi in ``[-1, 1]``. The DC bin
    is dropped, so ``n_bins - 1 = window // 2`` bins remain (the last is Nyquist for even K).
    ``phase="relative"``: each mic's phase minus the first mic's, wrapped to ``(-pi, pi]`` (the angle
    of its cross-spectrum with the first mic), so the source signal's own phase cancels and a
    plane wave gives ``-2 pi f tau_m`` at frequency ``f`` for the mic's delay ``tau_m`` after the
    first; the first mic's channel is then zero (kept, so both phases give the same shape).
    """
    if phase not in SPECTROGRAM_PHASES:
        raise ConfigError(f"spectrogram phase must be one of {', '.join(SPECTROGRAM_PHASES)}, got {phase!r}")
    Xs = X[..., 1:]
    mag = Xs.abs()
    peak = mag.amax(dim=-1, keepdim=True)
    mag = mag / torch.where(peak > 0, peak, torch.ones_like(peak))
    angles = torch.angle(Xs * Xs[..., :1, :].conj() if phase == "relative" else Xs)
    return torch.cat([mag, angles / math.pi], dim=-2)


def zero_silent(features: torch.Tensor, vad: torch.Tensor | None) -> torch.Tensor:
    """Zero the frames where ``vad`` is False.

    ``features``: ``(batch, frames, ...)``; ``vad``: ``(batch, frames)`` bool or None (no-op).
    """
    if vad is None:
        return features
    mask = vad.to(device=features.device, dtype=torch.bool).reshape(vad.shape + (1,) * (features.ndim - 2))
    return torch.where(mask, features, torch.zeros((), dtype=features.dtype, device=features.device))
