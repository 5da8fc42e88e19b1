"""The hold rule of the causal models: after a long silence, repeat the last estimate.

A causal model sees only its receptive field (Cross3D 16x32: 37 frames, 7.2 s). Once a silence
fills it the input holds no trace of the talker and the output wanders (on the sim-train v2
validation set, cross3d:16x32 erred by 7-14 deg up to 30 silent frames and by 56-87 deg beyond).
So after ``frames`` consecutive voice-inactive frames the estimate from before that point is
repeated until someone speaks again; before the first voice-active frame there is nothing to hold
and the model's output passes through. :class:`SilenceHold` wraps a tracker's stream of
directions, frame by frame (:meth:`~SilenceHold.step`) or a whole episode at once
(:meth:`~SilenceHold.episode`, the same directions).
"""
from __future__ import annotations

import numpy as np

import doabench
from doabench.errors import ConfigError

_NEVER_VOICED = 1 << 62  # silent-run count before the first voice-active frame
#: the values that switch an option off (``hold``, Cross3D's ``refine``)
OFF_VALUES = ("off", "none", "false", "0", "no")


def parse_hold(value: str | int) -> int | None:
    """The ``hold`` option: None for ``auto``, 0 for ``off``, else a positive frame count."""
    text = str(value).strip().lower()
    if text == "auto":
        return None
    if text in OFF_VALUES:
        return 0
    try:
        frames = int(text)
    except ValueError:
        frames = -1
    if frames < 1:
        raise ConfigError(f"hold must be auto, off or a number of frames >= 1, got {value!r}")
    return frames


class SilenceHold:
    """Holds a stream of directions ``(3,)`` once ``frames`` consecutive frames were voice-inactive."""

    def __init__(self, frames: int) -> None:
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
        return self._held.copy()

    def episode(self, directions: np.ndarray, vad: np.ndarray) -> np.ndarray:
        """``(frames, 3)`` directions of a whole episode, held as :meth:`step` holds them."""
        return doabench.hold_in_silences(directions, np.asarray(vad, bool), self.frames)
