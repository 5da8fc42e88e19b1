"""``doabench migrate FOLDER``: rename results files to the names this version gives them."""
from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("migrate", help="rename a folder's results files to this version's names",
                       description="Rename the results files of FOLDER (JSON and CSV) to the names this version "
                                   "derives from what they hold (shipped weights by name: "
                                   "sim-walk__cross3d_16x32__moving-long.json). Contents are not changed. "
                                   "--dry-run lists the renames.")
    p.add_argument("folder", help="a folder of results files (e.g. results)")
    p.add_argument("--dry-run", action="store_true", help="list the renames, change nothing")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from doabench.results.migrate import apply_renames, plan_renames

    renames = plan_renames(args.folder)
    for r in renames:
        print(f"{r.source.name} -> {r.target.name}")
    if not renames:
        print(f"{args.folder}: every results file has its current name")
    elif args.dry_run:
        print(f"{len(renames)} files to rename (--dry-run: nothing changed)")
    else:
        apply_renames(renames)
        print(f"renamed {len(renames)} results files (and their CSV files) in {args.folder}")
    return 0
