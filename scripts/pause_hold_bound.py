#!/usr/bin/env python3
"""How well can any tracker that holds its last direction do on a task with pauses?

Reads results files written with per-frame estimates (``doabench run`` without ``--no-frames``)
and prints, per file, the tracker's all-frames and non-silent RMSAE next to an oracle that knows
the true direction at every voice-active frame and holds the last one through silent frames.
Frames before the first voice-active frame have no direction to hold; the oracle scores them 90°.
The bound depends on how far the source moves while silent. It is not a limit for trackers that
extrapolate the motion (a Kalman filter does). It does show when a hold target is out of reach for
the task as designed.

    doabench run --tracker cross3d:16x32 --task sim-pauses --librispeech PATH --out runs/pauses
    python scripts/pause_hold_bound.py runs/pauses/sim-pauses__cross3d_16x32.json
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def _unit(a) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def hold_last_voiced(truth: np.ndarray, vad: np.ndarray, valid: np.ndarray | None = None,
                     planar: bool = False) -> np.ndarray:
    """Per-frame error ``(scored frames,)`` of holding the true direction of the last voice-active
    frame (90° before the first one), scored as ``doabench run`` scores (invalid truth left out,
    planar arrays folded). ``truth`` ``(frames, 3)`` unit vectors, ``vad`` ``(frames,)``."""
    from doabench.metrics import score_frames

    idx = np.where(vad, np.arange(len(vad)), -1)
    last = np.maximum.accumulate(idx)  # index of the last voice-active frame so far, -1 before any
    scored = score_frames(truth[np.maximum(last, 0)], truth, vad, valid, planar)
    err = scored.errors.copy()
    err[(last < 0)[scored.keep]] = 90.0
    return err


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", nargs="+", type=Path, help="results JSON files with per-frame estimates")
    args = ap.parse_args(argv)
    from doabench.metrics import score_frames

    print("| results file | tracker RMSAE all | tracker RMSAE non-silent | hold-the-truth oracle RMSAE all |")
    print("|---|---|---|---|")
    rms = lambda parts: float(np.sqrt(np.mean(np.concatenate(parts) ** 2)))  # noqa: E731
    pooled: list[list[np.ndarray]] = [[], [], []]  # over every file: errors, voice-active errors, oracle
    for path in args.results:
        try:
            r = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            print(f"error: cannot read {path}: {exc}", file=sys.stderr)
            return 2
        if not r.get("frames"):
            print(f"error: {path} has no per-frame estimates (written with --no-frames?)", file=sys.stderr)
            return 2
        planar = bool((r.get("scoring") or {}).get("planar_fold"))
        errs, voiced, oracle = [], [], []
        for fr in r["frames"]:
            truth, vad = _unit(fr["truth"]), np.asarray(fr["vad"], dtype=bool)
            scored = score_frames(_unit(fr["estimates"]), truth, vad, fr.get("valid"), planar)
            errs.append(scored.errors)
            voiced.append(scored.errors[scored.vad])
            oracle.append(hold_last_voiced(truth, vad, fr.get("valid"), planar))
        print(f"| {path.name} | {rms(errs):.2f} | {rms(voiced):.2f} | {rms(oracle):.2f} |")
        for whole, part in zip(pooled, (errs, voiced, oracle)):
            whole.extend(part)
    if len(args.results) > 1:  # e.g. the cells of a grid, one file each: pooled over their frames
        errs, voiced, oracle = pooled
        print(f"| all {len(args.results)} files, pooled | {rms(errs):.2f} | {rms(voiced):.2f} | {rms(oracle):.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
