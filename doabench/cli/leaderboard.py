"""``doabench leaderboard``: Markdown and CSV tables per task from the results files."""
from __future__ import annotations

import argparse
import shlex
from pathlib import Path

def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("leaderboard", help="build leaderboard tables from results files",
                       description="Write one Markdown table and one CSV per task (grid tasks also get per-cell "
                                   "tables and a cells CSV) plus summary.md, from the results JSON files. Complete "
                                   "runs are ranked; partial runs (n of N episodes) are ranked apart, under them. "
                                   "Output is deterministic: the same inputs give byte-identical files.")
    # Defaults under the git-ignored runs/, where `doabench run` writes by default: building a
    # leaderboard never rewrites the committed leaderboards/ unless asked to (make update-demo-results).
    p.add_argument("--results", action=_Folders, default=["runs/results"], metavar="FOLDER",
                   help="folder of results JSON files, repeatable: the folders are read together, and a "
                        "configuration with files in two of them is shown once per folder, each row naming its "
                        "folder and episodes (default: runs/results/, where doabench run writes; the committed "
                        "ones: --results results)")
    p.add_argument("--out", default="runs/leaderboards",
                   help="output folder (default: runs/leaderboards/, git-ignored; the committed tables: "
                        "--out leaderboards)")
    p.add_argument("--reference", action="append", metavar="CSV",
                   help="CSV of published reference rows (repeatable; default: OUT/locata-paper-table2.csv if present)")
    p.add_argument("--check", action="store_true",
                   help="write nothing; exit 1 if any generated file in OUT is missing or differs")
    p.set_defaults(func=main)


class _Folders(argparse.Action):
    """A repeatable folder option whose first use replaces the default (``append`` would add to it)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, value: object,
                 option_string: str | None = None) -> None:
        given = getattr(namespace, self.dest)
        setattr(namespace, self.dest, (given if given is not self.default else []) + [value])


def _command(args: argparse.Namespace) -> str:
    """The command line printed in the tables: the folders as given, so re-running it regenerates them."""
    parts = [part for folder in args.results for part in ("--results", folder)] + ["--out", args.out]
    for ref in args.reference or []:
        parts += ["--reference", ref]
    return "doabench leaderboard " + " ".join(shlex.quote(p) for p in parts)


def main(args: argparse.Namespace) -> int:
    from doabench.reporting.leaderboard import build_leaderboards, default_references, stale_files, write_leaderboards

    references = list(args.reference or []) or default_references(args.out)
    files = build_leaderboards(args.results, references, command=_command(args))
    if args.check:
        stale = stale_files(files, args.out)
        for name in stale:
            print(f"stale or missing: {Path(args.out) / name}")
        if not stale:
            print(f"{len(files)} leaderboard files in {args.out} are up to date")
        return 1 if stale else 0
    written = write_leaderboards(files, args.out)
    for path in written:
        print(f"wrote {path}")
    print(f"{len(files)} files in {args.out} ({len(written)} changed)")
    return 0
