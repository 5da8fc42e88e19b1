"""Maintainers: a Markdown table of a training run's progress from its log.csv (every Nth epoch, the best, the last).

    python scripts/run_progress.py training-runs/cross3d-16x32/log.csv [--every 5]
    python scripts/run_progress.py training-runs/cross3d-32x64-moving/log.csv --against training-runs/cross3d-16x32-moving/log.csv

The numbers are the log's, rounded; the model cards in docs/model-cards.md show the same table
(scripts/docs_site.py imports :func:`progress_table`).
"""
from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

HEADER = ("| epoch | SNR (dB) | batch | train loss | val RMSAE all (deg) | val RMSAE non-silent (deg) "
          "| val RMSAE all, held in silences (deg) | trajectories seen | compute (h) | trajectories/s |\n"
          "|---|---|---|---|---|---|---|---|---|---|\n")


def best_by(log: Path) -> str:
    """The column the run selects its best epoch by (config.json beside the log; runs started
    before the held score existed select by all frames)."""
    config = log.parent / "config.json"
    return json.loads(config.read_text()).get("best_by", "val_rmsae_all") if config.exists() else "val_rmsae_all"


def progress_table(log: Path, every: int) -> str:
    rows = list(csv.DictReader(log.open()))
    if not rows:
        raise SystemExit(f"{log}: no epochs yet")
    key = best_by(log)
    best = min((r for r in rows if r.get(key)), key=lambda r: float(r[key]))
    lines = []
    for i, r in enumerate(rows):
        if int(r["epoch"]) % every and i != len(rows) - 1 and r is not best:
            continue
        mark = " (best)" if r is best else ""
        held = f"{float(r['val_rmsae_held']):.2f}" if r.get("val_rmsae_held") else "-"
        lines.append(f"| {r['epoch']}{mark} | {r['phase_snr']} | {r['batch_size']} | {float(r['train_loss']):.4f} "
                     f"| {float(r['val_rmsae_all']):.2f} | {float(r['val_rmsae_nonsilent']):.2f} | {held} "
                     f"| {int(r['trajectories_seen']):,} | {float(r['compute_s']) / 3600:.2f} "
                     f"| {float(r['trajectories_per_s']):.2f} |\n")
    return HEADER + "".join(lines)


def side_by_side(log: Path, other: Path) -> str:
    """Two runs' validation at the epochs both have (a pilot against the run it should beat): loss,
    RMSAE all frames, voice-active and held in silences, ``this / other``, and the difference of the
    loss."""
    mine = {r["epoch"]: r for r in csv.DictReader(log.open())}
    theirs = {r["epoch"]: r for r in csv.DictReader(other.open())}
    lines = ["| epoch | val loss | val RMSAE all (deg) | val RMSAE non-silent (deg) | val RMSAE held (deg) |\n"
             "|---|---|---|---|---|\n"]
    for epoch in sorted(set(mine) & set(theirs), key=int):
        a, b = mine[epoch], theirs[epoch]
        cells = [f"{float(a['val_loss']):.4f} / {float(b['val_loss']):.4f}"]
        cells += [f"{float(a[k]):.2f} / {float(b[k]):.2f}" for k in ("val_rmsae_all", "val_rmsae_nonsilent", "val_rmsae_held")]
        lines.append(f"| {epoch} | " + " | ".join(cells) + " |\n")
    return "".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", type=Path)
    ap.add_argument("--every", type=int, default=5)
    ap.add_argument("--against", type=Path, metavar="LOG",
                    help="instead: this run's validation beside another run's at the same epochs (this / other)")
    args = ap.parse_args()
    sys.stdout.write(side_by_side(args.log, args.against) if args.against else progress_table(args.log, args.every))


if __name__ == "__main__":
    main()
