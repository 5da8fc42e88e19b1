"""``doabench migrate PATH``: a folder's results files in this version's schema and names, or a
weights file's copy in this version's metadata format."""
from __future__ import annotations

import argparse
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("migrate", help="bring a folder's results files, or a weights file, to this version's formats",
                       description="FOLDER: rewrite its results files of an older schema in the current one "
                                   "(in place, atomically; their CSV files are left as they are), then rename the "
                                   "results files (JSON and CSV) to the names this version derives from what they "
                                   "hold (shipped weights by name: sim-walk__cross3d_16x32__moving-long.json). "
                                   "WEIGHTS.safetensors: write a copy with its metadata in the current format "
                                   "(--out; default WEIGHTS-migrated.safetensors beside it) and print its SHA-256. "
                                   "--dry-run lists what would change.")
    p.add_argument("path", metavar="PATH", help="a folder of results files (e.g. results), or a .safetensors weights file")
    p.add_argument("--out", metavar="FILE", help="where a weights file's migrated copy goes")
    p.add_argument("--dry-run", action="store_true", help="list the changes, change nothing")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    path = Path(args.path)
    if path.suffix == ".safetensors" and not path.is_dir():
        return _weights(path, args)
    if args.out:
        from doabench.errors import InputError

        raise InputError("--out is for a weights file; a folder of results files is migrated in place")
    return _folder(path, args.dry_run)


def _weights(path: Path, args: argparse.Namespace) -> int:
    from doabench.results.migrate import migrate_weights
    from doabench.results.upgrade import WEIGHTS_FORMAT

    out = Path(args.out) if args.out else path.with_name(f"{path.stem}-migrated.safetensors")
    if args.dry_run:
        print(f"{path} -> {out} ({WEIGHTS_FORMAT}; --dry-run: nothing written)")
        return 0
    found, digest = migrate_weights(path, out)
    if digest is None:
        print(f"{path} is {WEIGHTS_FORMAT} already: nothing written")
        return 0
    print(f"{path} ({found}) -> {out} ({WEIGHTS_FORMAT}), sha256 {digest}")
    return 0


def _folder(folder: Path, dry_run: bool) -> int:
    from doabench.results.migrate import apply_renames, plan_renames, plan_rewrites, rewrite_results
    from doabench.results.upgrade import RESULTS_SCHEMA

    rewrites = plan_rewrites(folder)
    for r in rewrites:
        if not dry_run:
            rewrite_results(r)
        print(f"{r.path.name}: {r.version} -> {RESULTS_SCHEMA}" + (" (--dry-run)" if dry_run else ""))
    renames = plan_renames(folder)
    for rename in renames:
        print(f"{rename.source.name} -> {rename.target.name}")
    if not rewrites and not renames:
        print(f"{folder}: every results file is in {RESULTS_SCHEMA} and has its current name")
    elif dry_run:
        print(f"{len(rewrites)} files to rewrite, {len(renames)} to rename (--dry-run: nothing changed)")
    else:
        apply_renames(renames)
        print(f"{folder}: rewrote {len(rewrites)} results files in {RESULTS_SCHEMA}, renamed {len(renames)} "
              "(and their CSV files)")
    return 0
