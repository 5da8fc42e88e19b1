"""Trackers: the public base class, the registry and the built-in classical trackers."""
from doabench.trackers.base import Tracker
from doabench.trackers.registry import available_trackers, make_tracker, register_tracker, resolve_tracker

__all__ = ["Tracker", "available_trackers", "make_tracker", "register_tracker", "resolve_tracker"]
