"""Trackers: the public base class, the registry and the built-in classical trackers.

``parse_resolution`` (and its inverse ``resolution_text``) is here for tracker specs that carry a grid (``cross3d:16x32``,
``srp-max:32x64``): every learned or classical tracker with a resolution parses it the same way.
"""
from doabench.geometry import parse_resolution, resolution_text
from doabench.trackers.base import Tracker
from doabench.trackers.hold import SilenceHold, held_frame_index, hold_in_silences
from doabench.trackers.registry import available_trackers, make_tracker, register_tracker, resolve_tracker

__all__ = ["SilenceHold", "Tracker", "available_trackers", "held_frame_index", "hold_in_silences", "make_tracker", "parse_resolution",
           "register_tracker", "resolution_text", "resolve_tracker"]
