"""The ``doabench`` command line.

Each subcommand lives in its own module ``doabench/cli/<name>.py`` exposing
``register(subparsers)``; that function adds its parser and sets ``func`` (``args -> int``).
User errors (:class:`doabench.errors.DoabenchError`) become one line on stderr and exit code 2;
so does an output that cannot be written (full disk, read-only folder, permission, quota). Ctrl-C
and SIGTERM stop a command with one line saying what was kept and the command that resumes it
(a subcommand sets ``args.interrupt_note``, see :func:`doabench.cli.common.set_interrupt_note`).
When an output goes to standard output (``--out -``, ``--out /dev/stdout``), the command's own
messages go to standard error, so they do not mix with the data.
"""
from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import signal
import sys
import warnings

from doabench._version import __version__
from doabench.errors import DoabenchError, Interrupted

# Order is the order of `doabench --help`.
SUBCOMMAND_MODULES = (
    "run",
    "track",
    "listing",
    "describe",
    "features",
    "simulate",
    "data",
    "make_dataset",
    "dataset",
    "train",
    "export",
    "leaderboard",
    "compare",
    "locata_eval",
    "sweep",
    "plot",
    "migrate",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="doabench",  # also for `python -m doabench`
        description="Benchmark and dataset generator for sound source DOA estimation and tracking.",
    )
    parser.add_argument("--version", action="version", version=f"doabench {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMAND_MODULES:
        try:
            module = importlib.import_module(f"doabench.cli.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"doabench.cli.{name}":
                continue  # subcommand not built yet
            raise
        module.register(sub)
    return parser


def one_line_warnings(command: str):
    """A ``warnings.showwarning`` that prints ``doabench COMMAND: warning: MESSAGE`` as one line,
    like the errors: Python's default adds the file, line number and source line of the call,
    which tell a command-line user nothing."""
    def show(message, category, filename, lineno, file=None, line=None) -> None:
        print(f"doabench {command}: warning: {' '.join(str(message).split())}", file=file or sys.stderr)

    return show


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 1
    args.argv = list(sys.argv[1:] if argv is None else argv)
    with warnings.catch_warnings():  # restores Python's own format when main() returns
        warnings.showwarning = one_line_warnings(args.command)
        with _stop_signals(), _messages_apart_from_data(args):
            return _run(args)


# The options that name an output file or folder (checked for standard output).
OUTPUT_OPTIONS = ("out", "plot", "export")


@contextlib.contextmanager
def _messages_apart_from_data(args: argparse.Namespace):
    """Print the command's messages on standard error when one of its outputs is standard output."""
    from doabench.files import writes_to_stdout

    if any(writes_to_stdout(getattr(args, name, None)) for name in OUTPUT_OPTIONS):
        with contextlib.redirect_stdout(sys.stderr):
            yield
    else:
        yield


def _raise_interrupted(signum: int, frame) -> None:
    # Once: a second signal while the first one's cleanup runs (temporary files removed, locks
    # released) must not cut that cleanup short. SIGKILL still stops the process.
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)
    raise Interrupted("Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name)


@contextlib.contextmanager
def _stop_signals():
    """SIGINT (Ctrl-C) and SIGTERM raise :class:`~doabench.errors.Interrupted` (a
    KeyboardInterrupt) in the main thread, so every cleanup runs; the handlers before are restored."""
    saved = {}
    try:
        for sig in (signal.SIGINT, signal.SIGTERM):
            saved[sig] = signal.signal(sig, _raise_interrupted)
    except ValueError:  # not the main thread (main() called from a thread): leave the signals alone
        pass
    try:
        yield
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)


def _run(args: argparse.Namespace) -> int:
    from doabench.files import write_error_reason

    try:
        return int(args.func(args) or 0)
    except DoabenchError as exc:
        print(f"doabench {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt as exc:
        how = exc.signal_name if isinstance(exc, Interrupted) else "Ctrl-C"
        note = getattr(args, "interrupt_note", None)
        try:
            kept = note() if note is not None else "nothing was written"
        except Exception:  # the note is a courtesy: never a traceback instead of it
            kept = "see the output folder for what was kept"
        print(f"doabench {args.command}: stopped by {how}; {kept}", file=sys.stderr)
        return 130 if how == "Ctrl-C" else 128 + getattr(signal, how, signal.SIGTERM)
    except BrokenPipeError:  # e.g. `doabench list tasks | head`
        os.dup2(os.open(os.devnull, os.O_WRONLY), 1)  # fd 1 itself: sys.stdout may be stderr here
        return 0
    except OSError as exc:
        # A write the command did not route through results.files (a library's own file, a log):
        # a full disk or a read-only folder is still one line, not a traceback.
        reason = write_error_reason(exc)
        if reason is None:
            raise
        where = f"cannot write {exc.filename}: " if exc.filename else "cannot write: "
        print(f"doabench {args.command}: error: {where}{reason}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
