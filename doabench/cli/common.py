"""Options shared by several subcommands."""
from __future__ import annotations

import argparse
import dataclasses
import os
import shlex
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable

if TYPE_CHECKING:
    from doabench.trackers.base import Tracker
    from doabench.trackers.registry import TrackerRef


def add_tracker_options(p: argparse.ArgumentParser, required: bool = True, default: str | None = None,
                        help: str = "tracker id (srp-max, srp-max:32x64, cross3d:16x32) or "
                                    "package.module:Class[:spec]") -> None:
    p.add_argument("--tracker", required=required, default=default, help=help)
    p.add_argument("--tracker-opt", action="append", default=[], metavar="KEY=VALUE",
                   help="option passed to the tracker's constructor (repeatable), e.g. weights=FILE")


def make_checked_tracker(tracker_id: str | TrackerRef, options: dict[str, Any]) -> Tracker:
    """The tracker a command is about to run or export, refused with one line (exit 2) when it is a
    learned model without trained weights and ``weights=random`` was not given.

    The warnings the tracker raises while it is built are held back until it passes that check:
    a learned tracker warns Python callers that it fell back to random weights, which on the
    command line would only repeat, above it, what the refusal says."""
    from doabench.runner import check_trained
    from doabench.trackers.registry import make_tracker

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        tracker = make_tracker(tracker_id, **options)
    check_trained(tracker)
    for w in caught:
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return tracker


def corpus_option_fields(only: Iterable[str] | None = None) -> list[dataclasses.Field]:
    """The task kinds' options that have a flag (:mod:`doabench.envs.options`), each once, in
    order; ``only``: these option names."""
    from doabench.envs.options import BUILTIN_KIND_OPTIONS

    seen: dict[str, dataclasses.Field] = {}
    for options in BUILTIN_KIND_OPTIONS:
        for f in dataclasses.fields(options):
            if "flag" in f.metadata and f.name not in seen and (only is None or f.name in only):
                seen[f.name] = f
    return list(seen.values())


def add_corpus_options(p: argparse.ArgumentParser, only: Iterable[str] | None = None) -> None:
    """The flags of the task kinds' run-time options (``--librispeech``, ``--locata-root``,
    ``--split``, ``--vad``, ``--backend``, ``--device``), built from their options dataclasses."""
    for f in corpus_option_fields(only):
        meta = f.metadata
        choices = list(meta["choices"]) if "choices" in meta else None  # None: argparse's own default
        p.add_argument(meta["flag"], default=meta.get("cli_default"), help=meta["help"], choices=choices)


def add_threads_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--threads", type=int, default=1,
                   help="torch CPU threads of this process (default 1: with the other cores busy, two threads made a "
                        "Cross3D run 4-12x slower; on an idle 2-core machine they gained nothing)")


def use_threads(args: argparse.Namespace) -> None:
    """Set torch's CPU thread count from ``--threads`` (validated: a one-line error below 1; None,
    where a command's default is its own choice, leaves it as it is).

    One by default: an evaluation is many small ops per frame and per episode, and an OpenMP
    region waits for its slowest thread, so a descheduled thread stalls it (docs/performance.md,
    "Threads of doabench run and sweep"). Parallelism comes from processes (`sweep --engine ray`)."""
    from doabench.errors import ConfigError

    if args.threads is None:
        return
    if args.threads < 1:
        raise ConfigError(f"--threads must be at least 1, got {args.threads}")
    import torch

    torch.set_num_threads(args.threads)


def command_line(args: argparse.Namespace, add: Iterable[str] = ()) -> str:
    """The command as it was typed (``doabench run ...``), quoted for a shell, with ``add``'s
    arguments appended where missing (``--resume``): what a stop message tells the user to run."""
    argv = list(getattr(args, "argv", None) or [])
    argv += [a for a in add if a not in argv]
    return shlex.join(["doabench", *argv])


def set_interrupt_note(args: argparse.Namespace, note: Callable[[], str]) -> None:
    """What ``doabench`` prints after "stopped by Ctrl-C;" when the command is interrupted: a
    function called then, so it can count what was kept (episodes journalled, parts written)."""
    args.interrupt_note = note


def corpus_kwargs(args: argparse.Namespace) -> dict:
    """The task options given by flags (not the device, which a command passes on its own)."""
    return {f.name: getattr(args, f.name) for f in corpus_option_fields()
            if f.name != "device" and getattr(args, f.name, None)}


def _same_file(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return a.expanduser().resolve() == b.expanduser().resolve()


def _check_writable_folder(folder: Path, option: str, target: Path) -> None:
    """The nearest existing ancestor of ``folder`` must be a writable folder (it is created below it)."""
    from doabench.errors import InputError

    probe = folder
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        raise InputError(f"{option} {target}: {probe} is not a folder")
    if not os.access(probe, os.W_OK | os.X_OK):
        try:
            read_only = bool(os.statvfs(probe).f_flag & os.ST_RDONLY)
        except OSError:
            read_only = False
        why = "is on a read-only file system" if read_only else "is not writable (permission denied)"
        raise InputError(f"{option} {target}: folder {probe} {why}")


def check_output_file(path: str | Path, inputs: Iterable[str | Path] = (), option: str = "--out") -> Path:
    """Refuse, before any computation, an output file that doabench never writes (a folder, a block
    device, a broken symbolic link: :func:`doabench.files.resolve_output`), that lies in an
    unwritable folder, or that is one of the inputs (writing it would destroy the input). A stream
    (``-``, a FIFO, a character device) is written through and needs no folder."""
    from doabench.errors import InputError, OutputError
    from doabench.files import resolve_output

    out = Path(path)
    try:
        target = resolve_output(path)
    except OutputError as exc:
        raise InputError(f"{option} {str(exc).removeprefix('cannot write ')}") from None
    if target.stream:
        return out
    assert target.path is not None, "standard output is a stream"
    for source in inputs:
        if source is not None and _same_file(target.path, Path(source)):
            raise InputError(f"{option} {out} is also an input ({source}); writing it would destroy that input")
    _check_writable_folder(target.path.parent if str(target.path.parent) else Path("."), option, out)
    return out


def check_output_folder(path: str | Path, option: str = "--out") -> Path:
    """Refuse, before any computation, an output folder that is a file, a stream (``-``, a FIFO,
    a device: a folder of files cannot be written through), a broken symbolic link, or that
    cannot be written. A symbolic link to a folder is followed."""
    from doabench.errors import InputError

    out = Path(path)
    if str(path) == "-":
        raise InputError(f"{option} - (standard output): this command writes a folder of files; give a folder")
    if out.is_symlink() and not out.exists():
        raise InputError(f"{option} {out} is a symbolic link to {os.path.realpath(out)}, which does not exist")
    if out.exists() and not out.is_dir():
        raise InputError(f"{option} {out} is a file, not a folder")
    _check_writable_folder(out, option, out)
    return out
