"""Compare two grid-task results files cell by cell: does each cell's RMSAE of the new run lie
inside the bootstrap 95 % interval of the reference run (and do the intervals overlap)?

Used to check that a simulator change does not move the sim-grid results (issue 13):

    python scripts/compare_grid_runs.py results/sim-grid__srp-max_32x64.json runs/check/sim-grid__srp-max_32x64.json

Prints a Markdown table and exits 1 when some cell's intervals do not overlap.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def load_cells(path: Path) -> dict:
    data = json.loads(Path(path).read_text())
    cells = data.get("cells")
    if not cells:
        raise SystemExit(f"{path}: no per-cell results (run a grid task such as sim-grid)")
    return {"task": data["task"], "cells": cells}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("reference", type=Path)
    ap.add_argument("new", type=Path)
    ap.add_argument("--metric", default="rmsae_all", choices=["rmsae_all", "rmsae_nonsilent"])
    args = ap.parse_args(argv)
    ref, new = load_cells(args.reference), load_cells(args.new)
    m = args.metric
    print(f"reference: {args.reference} (task v{ref['task'].get('version')}); "
          f"new: {args.new} (task v{new['task'].get('version')}); metric {m} (deg)\n")
    print("| cell | reference (95 % CI), n | new (95 % CI), n | new inside reference CI | CIs overlap |")
    print("|---|---|---|---|---|")
    apart = 0
    for cell, r in ref["cells"].items():
        n = new["cells"].get(cell)
        if n is None:
            print(f"| {cell} | {r[m]:.2f} | missing | | |")
            apart += 1
            continue
        (rl, rh), (nl, nh) = r[f"{m}_ci95"], n[f"{m}_ci95"]
        inside = rl <= n[m] <= rh
        overlap = nl <= rh and rl <= nh
        apart += not overlap
        print(f"| {cell} | {r[m]:.2f} ({rl:.2f}-{rh:.2f}), {r['n_episodes']} | {n[m]:.2f} ({nl:.2f}-{nh:.2f}), "
              f"{n['n_episodes']} | {'yes' if inside else 'no'} | {'yes' if overlap else 'NO'} |")
    print(f"\n{apart} cell(s) whose intervals do not overlap")
    return 1 if apart else 0


if __name__ == "__main__":
    sys.exit(main())
