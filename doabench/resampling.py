"""One rational resampler for every signal doabench reads at another rate (WAV recordings, LOCATA
array and source audio, speech corpora): ``scipy.signal.resample_poly`` with its default
Kaiser-windowed FIR anti-aliasing filter, the factors reduced by their greatest common divisor."""
from __future__ import annotations

import math

import numpy as np


def rational_factors(fs_in: int, fs_out: int) -> tuple[int, int]:
    """``(up, down)`` with ``fs_out / fs_in = up / down`` in lowest terms."""
    g = math.gcd(int(fs_in), int(fs_out))
    return int(fs_out) // g, int(fs_in) // g


def resample(x: np.ndarray, fs_in: int, fs_out: int, axis: int = -1) -> np.ndarray:
    """``x`` sampled at ``fs_in`` resampled to ``fs_out`` along ``axis`` (its dtype as
    ``resample_poly`` gives it); ``x`` itself as an array when the rates are equal."""
    up, down = rational_factors(fs_in, fs_out)
    if up == down == 1:
        return np.asarray(x)
    from scipy.signal import resample_poly  # scipy.signal takes ~0.3 s to import

    return resample_poly(x, up, down, axis=axis)
