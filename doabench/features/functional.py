"""Feature extraction as pure torch functions: STFT frames, GCC-PHAT, SRP-PHAT maps, spectrograms.

Conventions (see docs/features.md for the long version):

* Audio is ``(batch, n_mics, samples)``; frames follow :mod:`doabench.framing` (complete windows
  only, frame ``t`` covers samples ``[t * hop, t * hop + K)``).
* Window: **periodic** Hann, ``w[n] = 0.5 - 0.5 cos(2 pi n / K)`` (``torch.hann_window``'s default).
* Spectra ``X`` are ``(batch, frames, n_mics, K // 2 + 1)`` complex64.
* PHAT is applied per microphone, ``W_n = X_n / (|X_n| + eps)`` (the paper's ``G_n = 1 / |X_n|``),
  so the cross-spectrum of a pair is ``W_n W_m^*`` and a silent (all-zero) frame gives zeros.
* ``R_nm(tau) = (1/K) sum over all K bins of W_n W_m^* e^{j w_k tau}`` (``irfft``), which peaks at
  ``tau = tau_n - tau_m``: the delay of mic ``n`` relative to mic ``m``.
* Plane-wave delays in samples: ``tau_n(u) = -(r_n . u) fs / c`` (a mic closer to the source hears
  it earlier). An SRP map is ``sum over pairs n < m of R_nm(tau_n(u) - tau_m(u))``.

Everything is vectorised; the only Python loops are over fixed-size memory blocks (chunks of frames
or grid points), never over individual frames, pairs or grid points.
"""
from __future__ import annotations

import math
from typing import Literal, Sequence

import numpy as np
import torch

from doabench.errors import ConfigError, InputError
from doabench.geometry import SPEED_OF_SOUND, grid_unit_vectors

PHAT_EPS = 1e-12
DelayMode = Literal["nearest", "exact"]
DELAY_MODES = ("nearest", "exact")

# Working-set bounds for the blocked computations. Small blocks keep intermediates in cache, which
# matters more than GEMM size on memory-bound CPUs.
_GCC_BLOCK_BYTES = 2 << 20
_EXACT_BLOCK_BYTES = 32 << 20
# Above this many lags a full-length irfft is cheaper than evaluating each lag as a DFT row.
_DFT_MAX_LAGS = 64


# --------------------------------------------------------------------------------------------
# Frames and spectra
# --------------------------------------------------------------------------------------------
def hann_window(window: int, device: torch.device | str | None = None, dtype=torch.float32) -> torch.Tensor:
    """Periodic Hann window of ``window`` samples, shape ``(window,)``."""
    return torch.hann_window(window, periodic=True, device=device, dtype=dtype)


def n_bins(window: int) -> int:
    """Number of rfft bins of a ``window``-sample frame: ``window // 2 + 1``."""
    return window // 2 + 1


def rfft_weights(window: int, device=None, dtype=torch.float64) -> torch.Tensor:
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

    frames = frame_signal(x, window, hop).transpose(1, 2)  # (B, T, M, K) strided view
    # Writing the windowed frames straight into (B, T, M, K) order makes the spectra contiguous
    # in the order every consumer reads them.
    buf = torch.empty(frames.shape, dtype=x.dtype, device=x.device)
    torch.mul(frames, hann_window(window, x.device, x.dtype), out=buf)
    return torch.fft.rfft(buf, dim=-1)


def phat(X: torch.Tensor, eps: float = PHAT_EPS) -> torch.Tensor:
    """PHAT-whitened spectra ``X / (|X| + eps)``, same shape as ``X``."""
    return X / (X.abs() + eps)


# --------------------------------------------------------------------------------------------
# GCC-PHAT
# --------------------------------------------------------------------------------------------
def _as_pairs(pairs, n_mics: int, device) -> torch.Tensor:
    p = torch.as_tensor(np.asarray(pairs), dtype=torch.long, device=device)
    if p.ndim != 2 or p.shape[1] != 2:
        raise ConfigError(f"pairs must be (n_pairs, 2), got shape {tuple(p.shape)}")
    if p.numel() and (p.min() < 0 or p.max() >= n_mics):
        raise ConfigError(f"pairs refer to microphones outside 0..{n_mics - 1}")
    return p


def lag_dft_table(window: int, lags: torch.Tensor | Sequence[float], device=None) -> torch.Tensor:
    """Rows that turn an interleaved cross-spectrum into GCC values at the given lags.

    Returns ``(2 * (window // 2 + 1), n_lags)`` float32: for a cross-spectrum ``Phi`` laid out as
    ``view_as_real(Phi).reshape(..., 2 * n_bins)``, ``Phi_flat @ table`` is
    ``(1/K) sum_k a_k Re(Phi_k e^{j w_k tau})`` (= ``irfft(Phi)[tau]`` at integer ``tau``).
    """
    tau = torch.as_tensor(lags, dtype=torch.float64, device=device).reshape(-1)
    k = torch.arange(n_bins(window), dtype=torch.float64, device=device)
    phase = (2 * math.pi / window) * k[:, None] * tau[None, :]
    scale = (rfft_weights(window, device) / window)[:, None]
    table = torch.stack([scale * torch.cos(phase), -scale * torch.sin(phase)], dim=1)  # (F, 2, L)
    return table.reshape(2 * n_bins(window), tau.numel()).to(torch.float32)


def gcc_from_phat(
    W: torch.Tensor, pairs: torch.Tensor, max_lag: int, window: int, table: torch.Tensor | None = None
) -> torch.Tensor:
    """GCC-PHAT from already whitened spectra.

    ``W``: ``(batch, frames, n_mics, n_bins)`` complex; ``pairs``: ``(n_pairs, 2)`` long ->
    ``(batch, frames, n_pairs, 2 * max_lag + 1)`` real, lags ``-max_lag..max_lag``.
    ``table`` is :func:`lag_dft_table` for those lags (built if missing; ignored for many lags).
    """
    B, T, M, F = W.shape
    P = pairs.shape[0]
    n_lags = 2 * max_lag + 1
    out_dtype = W.real.dtype
    out = torch.empty((B, T, P, n_lags), dtype=out_dtype, device=W.device)
    if B * T == 0 or P == 0:
        return out
    use_dft = n_lags <= _DFT_MAX_LAGS
    if use_dft and table is None:
        table = lag_dft_table(window, torch.arange(-max_lag, max_lag + 1), W.device)
    if use_dft:
        table = table.to(device=W.device, dtype=out_dtype)
    i, j = pairs[:, 0], pairs[:, 1]
    Wf = W.reshape(B * T, M, F)
    flat_out = out.view(B * T, P, n_lags)
    # Cross-spectra of all pairs for all frames would be (frames x pairs x bins) complex, far
    # larger than cache; blocks of a few frames keep it there.
    block = max(1, _GCC_BLOCK_BYTES // (P * F * W.element_size()))
    for s in range(0, B * T, block):
        w = Wf[s : s + block]
        cross = w[:, i] * w[:, j].conj()  # (b, P, F)
        if use_dft:
            torch.matmul(torch.view_as_real(cross).reshape(-1, P, 2 * F), table, out=flat_out[s : s + block])
        else:
            r = torch.fft.irfft(cross, n=window, dim=-1)
            flat_out[s : s + block] = torch.cat([r[..., window - max_lag :], r[..., : max_lag + 1]], dim=-1)
    return out


def gcc_phat(
    X: torch.Tensor, pairs, max_lag: int, eps: float = PHAT_EPS, window: int | None = None
) -> torch.Tensor:
    """GCC-PHAT of microphone pairs.

    ``X``: ``(batch, frames, n_mics, n_bins)`` complex spectra (:func:`stft_frames`);
    ``pairs``: ``(n_pairs, 2)`` mic indices (``MicArray.pairs``); ``max_lag`` from
    ``MicArray.max_lag(fs)``. Returns ``(batch, frames, n_pairs, 2 * max_lag + 1)`` real for lags
    ``-max_lag..max_lag``: ``R_nm(tau) = irfft(W_n W_m^*)[tau]``, peaking at ``tau_n - tau_m``.
    ``window`` is the frame length K (default ``2 * (n_bins - 1)``, i.e. even K).
    """
    window = _window_of(X, window)
    if max_lag < 0 or max_lag >= window:
        raise ConfigError(f"max_lag {max_lag} outside 0..{window - 1}")
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
def plane_wave_delays(positions, directions, fs: float, c: float = SPEED_OF_SOUND) -> np.ndarray:
    """Arrival delays in samples of a plane wave from ``directions``.

    ``positions``: ``(n_mics, 3)`` metres; ``directions``: ``(..., 3)`` unit vectors towards the
    source. Returns ``(..., n_mics)`` float64, ``tau_n = -(r_n . u) fs / c``.
    """
    pos = np.asarray(positions, dtype=np.float64)
    u = np.asarray(directions, dtype=np.float64)
    return -(u @ pos.T) * (fs / c)


def grid_delays(positions, n_theta: int, n_phi: int, fs: float, planar: bool = False, c: float = SPEED_OF_SOUND) -> np.ndarray:
    """Delays of every grid direction, ``(n_mics, n_theta * n_phi)`` float64 samples (row-major grid)."""
    u = grid_unit_vectors(n_theta, n_phi, planar).reshape(-1, 3)
    return plane_wave_delays(positions, u, fs, c).T


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
    return (np.arange(len(pairs))[:, None] * n_lags + lag + max_lag).T.copy()


def srp_from_gcc(gcc: torch.Tensor, index: torch.Tensor, n_theta: int, n_phi: int) -> torch.Tensor:
    """Nearest-sample SRP maps from GCCs.

    ``gcc``: ``(batch, frames, n_pairs, n_lags)``; ``index``: ``(n_grid, n_pairs)`` from
    :func:`nearest_lag_index`. Returns raw maps ``(batch, frames, n_theta, n_phi)``.
    """
    B, T, P, L = gcc.shape
    table = gcc.reshape(B * T, P * L).t().contiguous()  # (P*L, B*T)
    # embedding_bag sums, for each grid point, the P table rows it names: a gather + sum over
    # pairs with no (grid x pairs x frames) intermediate.
    maps = torch.nn.functional.embedding_bag(index.to(gcc.device), table, mode="sum")  # (G, B*T)
    return maps.t().reshape(B, T, n_theta, n_phi)


def steering(tau: torch.Tensor, window: int) -> torch.Tensor:
    """Phase-alignment factors ``e^{j w_f tau_n(g)}``, ``(n_bins, n_mics, n_grid)`` complex64.

    ``tau``: ``(n_mics, n_grid)`` float64 samples; phases are formed in float64 before the cast.
    """
    k = torch.arange(n_bins(window), dtype=torch.float64, device=tau.device)
    phase = (2 * math.pi / window) * k[:, None, None] * tau.to(torch.float64)[None]
    return torch.polar(torch.ones_like(phase), phase).to(torch.complex64)


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
    ``steer``: optional precomputed :func:`steering` table. Returns ``(batch, frames, n_theta,
    n_phi)`` equal to ``sum_{n<m} R_nm(tau_n - tau_m)`` with ``R(tau) = (1/K)[Phi_0 +
    2 sum_k Re(Phi_k e^{j w_k tau}) + Re(Phi_{K/2} e^{j pi tau})]``.

    Computed as a PHAT beamformer ``Y_f(g) = sum_n W_n(f) e^{j w_f tau_n(g)}``: ``|Y|^2`` is the
    sum over all ordered pairs, so removing the diagonal ``sum_n |W_n|^2`` and halving leaves the
    unique-pair sum; the rfft weights turn the bin sum into the full-spectrum sum.
    """
    B, T, M, F = W.shape
    G = tau.shape[1]
    BT = B * T
    out = torch.empty((BT, G), dtype=W.real.dtype, device=W.device)
    if BT == 0:
        return out.reshape(B, T, n_theta, n_phi)
    a = rfft_weights(window, W.device, W.real.dtype)
    Wf = W.reshape(BT, M, F).permute(2, 0, 1).contiguous()  # (F, BT, M)
    diag = torch.einsum("f,fbm->b", a, Wf.real.square() + Wf.imag.square())  # (BT,)
    # Y for a block is (F, frames, grid points) complex; bound it.
    per_cell = F * W.element_size()
    cells = max(1, _EXACT_BLOCK_BYTES // per_cell)
    g_block = min(G, max(1, cells // max(1, min(BT, cells))))
    t_block = max(1, cells // g_block)
    tau = tau.to(W.device)
    for g0 in range(0, G, g_block):
        E = steer[:, :, g0 : g0 + g_block].to(W.device) if steer is not None else steering(tau[:, g0 : g0 + g_block], window)
        for t0 in range(0, BT, t_block):
            Y = torch.matmul(Wf[:, t0 : t0 + t_block], E)  # (F, bt, g)
            power = torch.view_as_real(Y).square().sum(-1)  # (F, bt, g)
            s = torch.tensordot(a, power, dims=([0], [0]))  # (bt, g)
            out[t0 : t0 + t_block, g0 : g0 + g_block] = s
    out = (out - diag[:, None]) / (2 * window)
    return out.reshape(B, T, n_theta, n_phi)


def srp_phat(
    X: torch.Tensor,
    positions,
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
    pairs = np.array([(i, j) for i in range(len(pos)) for j in range(i + 1, len(pos))], dtype=np.int64)
    d_max = float(np.linalg.norm(pos[:, None] - pos[None], axis=-1).max())
    max_lag = int(np.ceil(d_max / c * fs))
    index = torch.from_numpy(nearest_lag_index(tau, pairs, max_lag))
    gcc = gcc_from_phat(W, torch.from_numpy(pairs).to(X.device), max_lag, window)
    return srp_from_gcc(gcc, index, n_theta, n_phi)


def _check_resolution(n_theta: int, n_phi: int) -> None:
    if int(n_theta) < 2 or int(n_phi) < 2:
        raise ConfigError(f"resolution {n_theta}x{n_phi}: both N_theta and N_phi must be at least 2")


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
def spectrogram_features(X: torch.Tensor) -> torch.Tensor:
    """Magnitude and phase channels, ``(batch, frames, n_mics, n_bins)`` -> ``(batch, frames,
    2 * n_mics, n_bins - 1)`` float.

    Channels ``0..M-1``: each mic's magnitude divided by its maximum over frequency in that frame
    (an all-zero spectrum stays zero); channels ``M..2M-1``: phase / pi in ``[-1, 1]``. The DC bin
    is dropped, so ``n_bins - 1 = window // 2`` bins remain (the last is Nyquist for even K).
    """
    Xs = X[..., 1:]
    mag = Xs.abs()
    peak = mag.amax(dim=-1, keepdim=True)
    mag = mag / torch.where(peak > 0, peak, torch.ones_like(peak))
    return torch.cat([mag, torch.angle(Xs) / math.pi], dim=-2)


def zero_silent(features: torch.Tensor, vad: torch.Tensor | None) -> torch.Tensor:
    """Zero the frames where ``vad`` is False.

    ``features``: ``(batch, frames, ...)``; ``vad``: ``(batch, frames)`` bool or None (no-op).
    """
    if vad is None:
        return features
    mask = vad.to(device=features.device, dtype=torch.bool).reshape(vad.shape + (1,) * (features.ndim - 2))
    return torch.where(mask, features, torch.zeros((), dtype=features.dtype, device=features.device))
