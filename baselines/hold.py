"""The hold rule of the causal models: after a long silence, repeat the last estimate.

A causal model sees only its receptive field (Cross3D 16x32: 37 frames, 7.2 s). Once a silence
fills it the input holds no trace of the talker and the output wanders (on the sim-train v2
validation set, cross3d:16x32 erred by 7-14 deg up to 30 silent frames and by 56-87 deg beyond).
So after ``frames`` consecutive voice-inactive frames the estimate from before that point is
repeated until someone speaks again; before the first voice-active frame there is nothing to hold
and the model's output passes through. The rule itself is doabench's (:class:`doabench.SilenceHold`,
frame by frame or a whole episode at once); this module parses the trackers' ``hold`` option.
"""
from __future__ import annotations

from doabench import SilenceHold
from doabench.errors import ConfigError

__all__ = ["OFF_VALUES", "SilenceHold", "parse_hold"]

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
