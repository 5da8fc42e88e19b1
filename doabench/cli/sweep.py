"""``doabench sweep --trackers A,B --tasks X,Y --out DIR``: every run, then the leaderboard."""
from __future__ import annotations

import argparse

from doabench.cli.common import add_corpus_options, add_threads_option, corpus_kwargs, use_threads


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "sweep", help="run every (tracker, task) pair into one results folder, then build its leaderboard",
        description="Run each tracker of --trackers on each task of --tasks as `doabench run` does (same results "
                    "files, same resume journal and lock), into one --out folder, then write the leaderboard of "
                    "that folder. Run again after a crash: finished runs are skipped, interrupted ones resume. "
                    "Locally the runs go one after another; --engine ray runs them as Ray tasks "
                    "(docs/scale-out.md).")
    p.add_argument("--trackers", required=True, help="comma-separated tracker ids, e.g. srp-max,srp-max:32x64")
    p.add_argument("--tasks", required=True, help="comma-separated task ids, e.g. sim-demo,sim-t60-0.3-snr-30")
    p.add_argument("--tracker-opt", action="append", default=[], metavar="KEY=VALUE",
                   help="option passed to every tracker's constructor (repeatable)")
    p.add_argument("--episodes", type=int,
                   help="run only N episodes of each task (grid tasks: spread over the cells, as `doabench run "
                        "--episodes` does); partial runs are ranked apart from complete runs on the leaderboard")
    p.add_argument("--delays", choices=["nearest", "exact"], default=None,
                   help="SRP-PHAT delay mode (default: each tracker's trained one, else nearest)")
    p.add_argument("--out", default="runs/sweep",
                   help="results folder of every run (default: runs/sweep/, git-ignored)")
    p.add_argument("--leaderboard", metavar="DIR", help="leaderboard folder (default: OUT/leaderboard)")
    p.add_argument("--no-frames", action="store_true", help="do not store per-frame estimates in the JSON")
    p.add_argument("--engine", choices=["local", "ray"], default="local",
                   help="local (default): one run after another; ray: runs as Ray tasks (needs "
                        "pip install 'doabench[ray]')")
    p.add_argument("--ray-address", metavar="ADDR",
                   help="Ray cluster to use with --engine ray; default: a local Ray instance with --workers CPUs")
    p.add_argument("--workers", type=int, help="CPUs of the local Ray instance (default: 2 at most)")
    p.add_argument("--quiet", action="store_true", help="no progress bar (local engine)")
    p.add_argument("--replace", "--overwrite", dest="overwrite", action="store_true",
                   help="replace results files in the way whatever they hold, instead of refusing those runs: "
                        "without it a file of another configuration (another task version, other weights), or "
                        "one holding episodes the run does not take (4, then --episodes 2), fails its run before "
                        "the work. --overwrite is its older name")
    add_threads_option(p)  # of the local engine's runs; a Ray task gets its one CPU's thread from Ray
    add_corpus_options(p)
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from doabench.cli.common import check_output_folder
    from doabench.errors import ConfigError
    from doabench.sweep import sweep
    from doabench.trackers.registry import parse_options

    if args.ray_address and args.engine != "ray":
        raise ConfigError("--ray-address needs --engine ray")
    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {args.workers}")
    check_output_folder(args.out)
    use_threads(args)
    from doabench.cli.common import set_interrupt_note

    set_interrupt_note(args, lambda: _kept(args))
    env_options = corpus_kwargs(args)
    if args.device:
        env_options["device"] = args.device
    result = sweep(args.trackers, args.tasks, args.out, episodes=args.episodes, delays=args.delays,
                   tracker_options=parse_options(args.tracker_opt), keep_frames=not args.no_frames,
                   engine=args.engine, ray_address=args.ray_address, workers=args.workers,
                   leaderboard=args.leaderboard, log=lambda m: print(m, flush=True),
                   progress=not args.quiet and args.engine == "local", overwrite=args.overwrite, **env_options)
    n = len(result.runs)
    done = sum(r.status == "done" for r in result.runs)
    skipped = sum(r.status == "skipped" for r in result.runs)
    print(f"sweep: {n} runs ({done} run now, {skipped} already done, {len(result.failed)} failed) in {result.out}")
    if result.leaderboard is not None:
        print(f"leaderboard: {len(result.leaderboard_files)} files in {result.leaderboard}")
    for run in result.failed:
        print(f"failed: {run.tracker} on {run.task}: {run.error}")
    return 1 if result.failed else 0


def _kept(args: argparse.Namespace) -> str:
    """The stop message: finished runs' results files and interrupted runs' journals in --out."""
    from pathlib import Path

    from doabench.cli.common import command_line
    from doabench.results.schema import json_files
    from doabench.runner.journal import journal_count

    out = Path(args.out)
    results = json_files(out) if out.is_dir() else []
    journals = [p for p in out.glob(".*.partial.jsonl")] if out.is_dir() else []
    episodes = sum(journal_count(p) for p in journals)
    parts = [f"{len(results)} results file{'s' if len(results) != 1 else ''}"]
    if journals:
        parts.append(f"{episodes} finished episode{'s' if episodes != 1 else ''} of unfinished runs in their journals")
    return (f"kept {' and '.join(parts)} in {out}; resume with the same command (finished runs are skipped): "
            f"{command_line(args)}")
