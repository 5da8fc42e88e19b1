"""Voice activity detection of clean source signals (the paper's WebRTC VAD step).

The source signal is cut into 10 ms frames, each frame is classified by the WebRTC VAD
(``webrtcvad``, 16-bit PCM) and every sample inherits its frame's decision. The most aggressive
mode (3) is tried first; when it keeps fewer than ``min_active`` (66 %) of the samples active we
fall back to mode 2 and then mode 1, because mode 3 is known to drop quiet but genuine speech. If
even mode 1 keeps less, its decision is used as is.

The trailing samples that do not fill a whole frame are classified as part of one last frame
padded with zeros, so the per-sample VAD always has the signal's length.
"""
from __future__ import annotations

import numpy as np

from doabench.errors import ConfigError

WEBRTC_RATES = (8000, 16000, 32000, 48000)
FRAME_MS = 10
DEFAULT_MODES = (3, 2, 1)
MIN_ACTIVE = 0.66


def _pcm_frames(signal: np.ndarray, frame_len: int) -> np.ndarray:
    """``(L,)`` float in [-1, 1] -> ``(n_frames, frame_len)`` int16, zero-padded at the end."""
    n = -(-signal.shape[0] // frame_len)
    padded = np.zeros(n * frame_len, dtype=np.float64)
    padded[: signal.shape[0]] = signal
    pcm = np.clip(np.round(padded * 32767.0), -32768, 32767).astype("<i2")
    return pcm.reshape(n, frame_len)


def _frame_decisions(frames: np.ndarray, fs: int, mode: int) -> np.ndarray:
    import webrtcvad

    vad = webrtcvad.Vad(mode)
    # webrtcvad only takes bytes, one frame per call: this loop is the unavoidable part.
    return np.fromiter((vad.is_speech(f.tobytes(), fs) for f in frames), dtype=bool, count=len(frames))


def webrtc_vad(
    signal: np.ndarray,
    fs: int = 16000,
    modes: tuple[int, ...] = DEFAULT_MODES,
    min_active: float = MIN_ACTIVE,
) -> tuple[np.ndarray, int]:
    """Per-sample voice activity of a mono signal.

    ``signal``: ``(L,)`` float, full scale 1.0 (values beyond are clipped for the VAD only).
    Returns ``(vad (L,) bool, mode used)``: the first mode of ``modes`` whose decision keeps at
    least ``min_active`` of the samples active, else the last one.
    """
    x = np.asarray(signal)
    if x.ndim != 1:
        raise ConfigError(f"VAD needs a mono signal of shape (L,), got shape {x.shape}")
    if fs not in WEBRTC_RATES:
        raise ConfigError(f"WebRTC VAD supports sample rates {WEBRTC_RATES}, got {fs}")
    if not modes or any(m not in (0, 1, 2, 3) for m in modes):
        raise ConfigError(f"VAD modes must be a non-empty sequence of 0..3, got {modes}")
    length = x.shape[0]
    if length == 0:
        return np.zeros(0, dtype=bool), int(modes[0])
    frame_len = fs * FRAME_MS // 1000
    frames = _pcm_frames(x, frame_len)
    for mode in modes:
        decisions = _frame_decisions(frames, fs, mode)
        vad = np.repeat(decisions, frame_len)[:length]
        if vad.mean() >= min_active:
            break
    return vad, int(mode)


def clean_with_vad(signal: np.ndarray, fs: int = 16000, **kwargs) -> tuple[np.ndarray, np.ndarray, int]:
    """Zero the silent samples of ``signal`` ``(L,)`` (the paper removes background noise there).

    Returns ``(cleaned (L,) float32, vad (L,) bool, mode used)``; ``kwargs`` go to :func:`webrtc_vad`.
    """
    vad, mode = webrtc_vad(signal, fs, **kwargs)
    cleaned = np.where(vad, np.asarray(signal, dtype=np.float32), np.float32(0.0))
    return cleaned.astype(np.float32, copy=False), vad, mode
