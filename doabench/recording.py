"""Reading a user's multichannel recording, with every check a user needs a clear message for."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from doabench.arrays import MicArray
from doabench.errors import InputError, NotFoundError


def read_audio(path: str | Path) -> tuple[np.ndarray, int]:
    """``(n_channels, samples)`` float32 and the sample rate; unreadable files are InputErrors."""
    import soundfile as sf

    path = Path(path)
    if not path.exists():
        raise NotFoundError(f"recording {path} does not exist")
    if not path.is_file():
        raise InputError(f"recording {path} is not a file")
    try:
        data, sr = sf.read(str(path), dtype="float32", always_2d=True)
    except Exception as exc:  # libsndfile reports every unreadable file its own way
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"cannot read {path} as audio ({msg})") from None
    return np.ascontiguousarray(data.T), int(sr)


def resample(x: np.ndarray, sr: int, fs: int) -> np.ndarray:
    """Polyphase resampling (Kaiser-windowed anti-aliasing filter) of ``(channels, samples)``."""
    from scipy.signal import resample_poly

    g = math.gcd(sr, fs)
    return resample_poly(x, fs // g, sr // g, axis=-1).astype(np.float32)


def load_recording(path: str | Path, array: MicArray, fs: int, allow_resample: bool = False,
                   min_samples: int = 0) -> tuple[np.ndarray, bool]:
    """A recording checked against the array and the sample rate: ``((n_mics, samples), resampled)``.

    Errors: channel count not the array's, another sample rate (unless ``allow_resample``),
    non-finite samples, fewer than ``min_samples`` samples (e.g. one analysis window).
    """
    path = Path(path)
    audio, sr = read_audio(path)
    if audio.shape[0] != array.n_mics:
        raise InputError(f"{path} has {audio.shape[0]} channels but array {array.name!r} has "
                         f"{array.n_mics} microphones")
    if not np.all(np.isfinite(audio)):
        raise InputError(f"{path} contains NaN or infinite samples")
    resampled = False
    if sr != fs:
        if not allow_resample:
            raise InputError(f"{path} is sampled at {sr} Hz, not {fs} Hz: pass --resample to convert it")
        audio, resampled = resample(audio, sr, fs), True
    if audio.shape[-1] < min_samples:
        raise InputError(f"{path} has {audio.shape[-1]} samples at {fs} Hz, shorter than one "
                         f"{min_samples}-sample window")
    return audio, resampled
