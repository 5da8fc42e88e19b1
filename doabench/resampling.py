"""One rational resampler for every signal doabench reads at another rate (WAV recordings, LOCATA
array and source audio, speech corpora): ``scipy.signal.resample_poly`` with its default
Kaiser-windowed FIR anti-aliasing filter, the factors reduced by their greatest common divisor."""
from __future__ import annotations

import math

import numpy as np


#: The highest sample rate doabench reads or computes at (768 kHz, the highest PCM rate audio
#: interfaces offer): a WAV header may claim any 32-bit rate, and block sizes, filter lengths and
#: GCC lags grow with it (:class:`~doabench.framing.FrameSpec` takes no higher rate either).
MAX_SAMPLE_RATE = 768_000
#: The largest factor of a rational resampling: ``resample_poly``'s filter has ``20 max(up, down) + 1``
#: taps, so a WAV claiming 10,000,019 Hz would ask for a 200-million-tap filter (1.5 GiB). Every
#: pair of common rates has far smaller factors (44.1 to 16 kHz: 160/441; 44,056 Hz: 2000/5507).
MAX_RESAMPLE_FACTOR = 1 << 16


def rational_factors(fs_in: int, fs_out: int) -> tuple[int, int]:
    """``(up, down)`` with ``fs_out / fs_in = up / down`` in lowest terms; an InputError saying the
    size and the limit for a rate beyond :data:`MAX_SAMPLE_RATE` or factors
    beyond :data:`MAX_RESAMPLE_FACTOR`, before any filter is designed."""
    from doabench.errors import InputError

    fs_in, fs_out = int(fs_in), int(fs_out)
    for rate in (fs_in, fs_out):
        if not 1 <= rate <= MAX_SAMPLE_RATE:
            raise InputError(f"a sample rate of {rate} Hz is outside 1 to {MAX_SAMPLE_RATE} Hz")
    g = math.gcd(fs_in, fs_out)
    up, down = fs_out // g, fs_in // g
    if max(up, down) > MAX_RESAMPLE_FACTOR:
        raise InputError(f"resampling {fs_in} Hz to {fs_out} Hz takes the factors {up}/{down}, a filter of "
                         f"{20 * max(up, down) + 1} taps; the limit is a factor of {MAX_RESAMPLE_FACTOR} "
                         f"({20 * MAX_RESAMPLE_FACTOR + 1} taps)")
    return up, down


def resample(x: np.ndarray, fs_in: int, fs_out: int, axis: int = -1) -> np.ndarray:
    """``x`` sampled at ``fs_in`` resampled to ``fs_out`` along ``axis`` (its dtype as
    ``resample_poly`` gives it); ``x`` itself as an array when the rates are equal."""
    up, down = rational_factors(fs_in, fs_out)
    if up == down == 1:
        return np.asarray(x)
    from scipy.signal import resample_poly  # scipy.signal takes ~0.3 s to import

    return resample_poly(x, up, down, axis=axis)
