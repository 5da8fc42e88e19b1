"""The hold rule of causal learned trackers: repeat the last informed estimate in long silences.

A causal network sees only its receptive field; once a silence fills it, its input holds no trace
of the talker and its output wanders. After ``hold`` consecutive voice-inactive frames the
tracker reports its estimate of the frame before that silence became long until someone speaks
again; before the first voice-active frame there is nothing to hold and the estimate is kept.

The rule in one place, in both of its forms: :func:`held_frame_index` for a whole episode (the
learned trackers' batch path and the trainer's validation, which scores the weights the way the
tracker will run them) and :class:`SilenceHold` for a stream of frames (a tracker's ``step``),
whose :meth:`~SilenceHold.episode` is :func:`hold_in_silences`.
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


_NEVER_VOICED = 1 << 62  # silent-run count before the first voice-active frame


class SilenceHold:
    """The rule over a stream of directions ``(3,)``: :meth:`step` per frame, :meth:`episode` for a
    whole episode at once (the same directions, :func:`hold_in_silences`)."""

    def __init__(self, frames: int) -> None:
        if int(frames) < 1:
            raise ConfigError(f"hold must be >= 1 frame, got {frames!r}")
        self.frames = int(frames)
        self.reset()

    def reset(self) -> None:
        """Start a new episode: no voice yet, nothing held."""
        self._silent_run, self._held = _NEVER_VOICED, np.zeros(3)

    def step(self, direction: np.ndarray, voiced: bool) -> np.ndarray:
        """The direction to report for this frame, given the model's ``direction`` and the frame's VAD."""
        if voiced:
            self._silent_run = 0
        elif self._silent_run < _NEVER_VOICED:
            self._silent_run += 1
        if self._silent_run >= _NEVER_VOICED:  # no voice yet: nothing to hold
            return direction
        if self._silent_run < self.frames:  # voice within the last `frames` frames
            self._held = direction
            return direction
        return np.array(self._held, copy=True)

    def episode(self, directions: np.ndarray, vad: np.ndarray) -> np.ndarray:
        """``(frames, 3)`` directions of a whole episode, held as :meth:`step` holds them."""
        return hold_in_silences(directions, np.asarray(vad, bool), self.frames)
