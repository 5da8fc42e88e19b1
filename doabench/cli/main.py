"""The ``doabench`` command line.

Each subcommand lives in its own module ``doabench/cli/<name>.py`` exposing
``register(subparsers)``; that function adds its parser and sets ``func`` (``args -> int``).
User errors (:class:`doabench.errors.DoabenchError`) become one line on stderr and exit code 2.
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys
import warnings

from doabench._version import __version__
from doabench.errors import DoabenchError

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
    "sweep",
    "plot",
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
    with warnings.catch_warnings():  # restores Python's own format when main() returns
        warnings.showwarning = one_line_warnings(args.command)
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    try:
        return int(args.func(args) or 0)
    except DoabenchError as exc:
        print(f"doabench {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"doabench {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # e.g. `doabench list tasks | head`
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    sys.exit(main())
