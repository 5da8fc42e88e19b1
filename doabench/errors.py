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


class FeatureKindError(DoabenchError, RuntimeError):
    """A feature kind misbehaved: its ``compute`` or ``frame_shape`` raised, or what it returned
    is not what it declares (shape, real finite float32)."""


class DependencyError(DoabenchError, ImportError):
    """An optional dependency (gpuRIR, ...) is missing."""


class OutputError(DoabenchError):
    """An output cannot be written (full disk, read-only file system, permission, quota) or is a
    path doabench never writes (a folder, a block device, a broken symbolic link)."""


class Interrupted(KeyboardInterrupt):
    """The command was stopped by a signal (SIGTERM; Ctrl-C is SIGINT). A KeyboardInterrupt, so
    every ``finally`` and ``except BaseException`` cleanup runs as it does for Ctrl-C."""

    def __init__(self, signal_name: str = "SIGTERM") -> None:
        super().__init__(signal_name)
        self.signal_name = signal_name


def one_line(exc: BaseException) -> str:
    """``Type: first line of the message`` of an exception, for one-line errors."""
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__
