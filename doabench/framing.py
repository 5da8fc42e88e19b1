"""Frames, the one rule used everywhere (features, ground truth, VAD, environments).

* Frame ``t`` covers samples ``[t * hop, t * hop + K)``; only complete windows are kept, no
  padding, so a frame is available as soon as its last sample arrives (causal).
* ``n_frames = 1 + (n_samples - K) // hop`` for ``n_samples >= K`` (else 0, an error for features).
  20 s at 16 kHz with K = 4096, hop = 3072 gives the paper's 103 frames.
* Frame time (``frame_times``) is the window centre: ``(t * hop + K / 2) / fs`` seconds.
* A frame is *silent* unless more than 2/3 of its samples are voice-active (the paper's rule).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, cast, overload

import numpy as np
from numpy.typing import ArrayLike

from doabench.geometry import is_tensor
from doabench.resampling import MAX_SAMPLE_RATE

if TYPE_CHECKING:  # framing is imported without torch (gymnasium.make builds no features)
    import torch

DEFAULT_FS = 16000
DEFAULT_WINDOW = 4096
#: The longest analysis window (2**20 samples, 65 s at 16 kHz): its STFT tables and frames grow with it.
MAX_WINDOW = 1 << 20
ACTIVE_FRACTION = 2.0 / 3.0


@dataclass(frozen=True, init=False)
class FrameSpec:
    """Window length ``K`` (samples), hop (samples) and sample rate.

    ``hop=None`` means ``3 * window // 4``; the stored ``hop`` is always a number.
    """

    window: int
    hop: int
    fs: int

    # Written out rather than generated so that ``hop`` may be given as None while the field is an int.
    def __init__(self, window: int = DEFAULT_WINDOW, hop: int | None = None, fs: int = DEFAULT_FS) -> None:
        object.__setattr__(self, "window", window)
        object.__setattr__(self, "hop", 3 * window // 4 if hop is None else hop)
        object.__setattr__(self, "fs", fs)
        self.__post_init__()

    def __post_init__(self) -> None:
        from doabench.errors import ConfigError

        if self.window < 2 or self.hop < 1:
            raise ConfigError(f"invalid frame settings: window={self.window}, hop={self.hop}")
        if self.window > MAX_WINDOW:
            raise ConfigError(f"invalid frame settings: a window of {self.window} samples, more than the limit of "
                              f"{MAX_WINDOW}")
        if self.fs < 1:
            raise ConfigError(f"invalid frame settings: the sample rate must be a positive number of Hz, got {self.fs}")
        if self.fs > MAX_SAMPLE_RATE:
            raise ConfigError(f"invalid frame settings: a sample rate of {self.fs} Hz, more than the limit of "
                              f"{MAX_SAMPLE_RATE} Hz")

    def n_frames(self, n_samples: int) -> int:
        return n_frames(n_samples, self.window, self.hop)

    def times(self, n: int) -> np.ndarray:
        return frame_times(n, self.window, self.hop, self.fs)

    def to_dict(self) -> dict[str, int]:
        return {"window": self.window, "hop": self.hop, "fs": self.fs}


def n_frames(n_samples: int, window: int, hop: int) -> int:
    """Number of complete windows in ``n_samples`` samples."""
    return 0 if n_samples < window else 1 + (n_samples - window) // hop


def frame_times(n: int, window: int, hop: int, fs: int) -> np.ndarray:
    """Centre time in seconds of each of ``n`` frames, shape ``(n,)``."""
    return (np.arange(n) * hop + window / 2) / fs


@overload
def frame_signal(x: "torch.Tensor", window: int, hop: int) -> "torch.Tensor": ...
@overload
def frame_signal(x: np.ndarray, window: int, hop: int) -> np.ndarray: ...
def frame_signal(x: Any, window: int, hop: int) -> Any:
    """Split the last axis into frames: ``(..., samples)`` -> ``(..., frames, window)``.

    A strided view (no copy) for both numpy arrays and torch tensors.
    """
    n = n_frames(x.shape[-1], window, hop)
    if is_tensor(x):
        return x[..., : (n - 1) * hop + window].unfold(-1, window, hop) if n else x[..., :0].unsqueeze(-1)
    if n == 0:
        return np.zeros(x.shape[:-1] + (0, window), dtype=x.dtype)
    return np.lib.stride_tricks.sliding_window_view(x, window, axis=-1)[..., ::hop, :][..., :n, :]


@overload
def frame_vad(sample_vad: "torch.Tensor", window: int, hop: int) -> "torch.Tensor": ...
@overload
def frame_vad(sample_vad: Any, window: int, hop: int) -> np.ndarray: ...
def frame_vad(sample_vad: Any, window: int, hop: int) -> Any:
    """Per-sample VAD ``(..., samples)`` (bool or 0/1) -> per-frame VAD ``(..., frames)`` bool.

    A frame is active when more than 2/3 of its samples are active.
    """
    if is_tensor(sample_vad):
        tensor_frames = frame_signal(sample_vad.float(), window, hop)
        return tensor_frames.mean(-1) > ACTIVE_FRACTION
    frames = frame_signal(np.asarray(sample_vad, dtype=np.float32), window, hop)
    return frames.mean(-1) > ACTIVE_FRACTION


def samples_from_frame_vad(frame_active: ArrayLike, n_samples: int, window: int, hop: int) -> np.ndarray:
    """A per-sample VAD ``(n_samples,)`` bool whose :func:`frame_vad` is ``frame_active`` ``(T,)``:
    a sample is active when any frame covering it is. Exact when an inactive frame cannot collect
    more than 2/3 active samples from its neighbours (``hop >= 2K/3``; the default 3K/4 is);
    otherwise, or when ``T`` is not the frame count of ``n_samples``, a ConfigError. What
    ``doabench track --vad truth`` feeds the features from a truth table's per-frame vad column."""
    from doabench.errors import ConfigError

    active = np.asarray(frame_active, bool).reshape(-1)
    if len(active) != n_frames(n_samples, window, hop):
        raise ConfigError(f"{len(active)} frame VAD values for {n_samples} samples; the frames (K = {window}, "
                          f"hop {hop}) number {n_frames(n_samples, window, hop)}")
    out = np.zeros(n_samples, bool)
    for t in np.flatnonzero(active):
        out[t * hop:t * hop + window] = True
    if not np.array_equal(frame_vad(out, window, hop), active):
        raise ConfigError(f"frames with K = {window} and hop {hop} overlap too much for a per-frame VAD to be "
                          "turned into per-sample activity exactly (needs hop >= 2K/3)")
    return out


def frame_mean_directions(sample_dirs: np.ndarray, window: int, hop: int) -> np.ndarray:
    """Per-sample direction unit vectors ``(..., samples, 3)`` -> per-frame ``(..., frames, 3)``.

    The frame value is the mean over the window's samples, renormalised to unit length. Averaging
    unit vectors is the same as averaging angles with the azimuth unwrapped inside the window
    (for the small angular spans one window covers) and has no wrap-around problem.
    """
    from doabench.geometry import normalize

    d = np.moveaxis(np.asarray(sample_dirs, dtype=np.float64), -1, 0)  # (3, ..., samples)
    n = n_frames(d.shape[-1], window, hop)
    # A cumulative sum gives every window mean in one pass without materialising the frames.
    c = np.concatenate([np.zeros(d.shape[:-1] + (1,)), np.cumsum(d, axis=-1)], axis=-1)
    starts = np.arange(n) * hop
    means = (c[..., starts + window] - c[..., starts]) / window
    return cast(np.ndarray, normalize(np.moveaxis(means, 0, -1)))  # normalize keeps the array type
