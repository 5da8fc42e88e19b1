"""Markdown table of a training run's progress from its log.csv (every Nth epoch and the last).

    python scripts/run_progress.py training-runs/cross3d-16x32/log.csv [--every 5]

Used for docs/results.md ("Paper-scale runs"); the numbers are the log's, rounded.
"""
from __future__ import annotations

import argparse
import csv
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", type=Path)
    ap.add_argument("--every", type=int, default=5)
    args = ap.parse_args()
    rows = list(csv.DictReader(args.log.open()))
    if not rows:
        raise SystemExit(f"{args.log}: no epochs yet")
    best = min(rows, key=lambda r: float(r["val_rmsae_all"]))
    print("| epoch | SNR (dB) | batch | train loss | val RMSAE all (deg) | val RMSAE non-silent (deg) "
          "| trajectories seen | compute (h) | trajectories/s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for i, r in enumerate(rows):
        if (int(r["epoch"]) % args.every and i != len(rows) - 1) and r is not best:
            continue
        mark = " (best)" if r is best else ""
        print(f"| {r['epoch']}{mark} | {r['phase_snr']} | {r['batch_size']} | {float(r['train_loss']):.4f} "
              f"| {float(r['val_rmsae_all']):.2f} | {float(r['val_rmsae_nonsilent']):.2f} | {int(r['trajectories_seen']):,} "
              f"| {float(r['compute_s']) / 3600:.2f} | {float(r['trajectories_per_s']):.2f} |")


if __name__ == "__main__":
    main()
