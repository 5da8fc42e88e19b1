"""The hold rule of causal learned trackers: repeat the last informed estimate in long silences.

A causal network sees only its receptive field; once a silence fills it, its input holds no trace
of the talker and its output wanders. After ``hold`` consecutive voice-inactive frames the
tracker reports its estimate of the frame before that silence became long until someone speaks
again; before the first voice-active frame there is nothing to hold and the estimate is kept.

Pure numpy functions, shared by the learned trackers (``baselines``) and the trainer's
validation, which scores the weights the way the tracker will run them.
"""
from __future__ import annotations

import numpy as np

from doabench.errors import ConfigError


def held_frame_index(vad: np.ndarray, hold: int) -> np.ndarray:
    """Index ``(..., frames)`` int64 of the frame whose estimate each frame reports under the rule.

    ``vad`` ``(..., frames)`` bool (voice activity per frame; batched over leading axes), ``hold``
    the number of silent frames after which the estimate holds (>= 1). Frame ``t`` reports itself
    while a voice-active frame lies within its last ``hold`` frames (or none has come yet), else
    the last frame before it that did."""
    if int(hold) < 1:
        raise ConfigError(f"hold must be >= 1 frame, got {hold!r}")
    vad = np.asarray(vad, dtype=bool)
    index = np.broadcast_to(np.arange(vad.shape[-1], dtype=np.int64), vad.shape)
    last_voiced = np.maximum.accumulate(np.where(vad, index, -1), axis=-1)
    informed = (last_voiced >= 0) & (index - last_voiced < int(hold))
    return np.maximum.accumulate(np.where(informed | (last_voiced < 0), index, -1), axis=-1)


def hold_in_silences(directions: np.ndarray, vad: np.ndarray, hold: int) -> np.ndarray:
    """``directions`` ``(frames, 3)`` with every frame that ends a run of ``>= hold`` voice-inactive
    frames replaced by the last frame before it that did not (:func:`held_frame_index`); frames
    before the first voice-active one are left as they are. ``vad`` ``(frames,)`` bool."""
    held: np.ndarray = np.asarray(directions)[held_frame_index(vad, hold)]
    return held
