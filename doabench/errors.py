"""User-facing errors.

Every problem a user can cause (bad input file, wrong channel count, unknown task id, ...) raises a
:class:`DoabenchError` subclass with a one-line message that names the problem. The CLI prints the
message and exits non-zero instead of showing a traceback.
"""
from __future__ import annotations


class DoabenchError(Exception):
    """Base class of errors whose message is meant for the user."""

    exit_code = 2


class InputError(DoabenchError, ValueError):
    """Bad user input: a file, a parameter, a recording."""


class ConfigError(DoabenchError, ValueError):
    """A task spec, array file, tracker option or scene parameter is invalid."""


class NotFoundError(DoabenchError, KeyError):
    """An id (task, tracker, array) or a path that does not exist."""

    def __str__(self) -> str:  # KeyError quotes its message; we want plain text
        return str(self.args[0]) if self.args else ""


class TrackerError(DoabenchError, RuntimeError):
    """A tracker misbehaved (NaN output, wrong shape, ...)."""


class DependencyError(DoabenchError, ImportError):
    """An optional dependency (gpuRIR, ...) is missing."""
