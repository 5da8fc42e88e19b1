#!/usr/bin/env python3
"""Where a tracker's error sits: per run of silent frames, and with holding.

With ``--tracker``: scores a trainable tracker's network on the fixed validation set of
``doabench train`` (the 30 held-out-speaker trajectories of the training task, built in
``runs/cache`` if missing), the same frames the training log's validation columns pool; the
network runs raw (``hold=off``). With ``--results FILE [FILE ...]``: the per-frame estimates of
results files written without ``--no-frames`` (any tracker, any task; several files pool their
frames, e.g. one run per grid cell). Prints the RMSAE and share of the squared
error per number of frames since the last voice-active frame (and before the first one), then the
all-frames RMSAE when the estimate is held after ``N`` silent frames (``doabench.hold_in_silences``,
the rule the learned trackers' ``hold`` option applies) for each ``--holds`` value.

    python scripts/silence_errors.py --tracker cross3d:16x32 --librispeech ../shared/data/LibriSpeech
    python scripts/silence_errors.py --results runs/fig7/sim-grid__cross3d_16x32.json
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import torch

BUCKETS = ((1, 3), (3, 6), (6, 11), (11, 21), (21, 31), (31, 41), (41, None))


def frames_since_voice(vad: np.ndarray) -> np.ndarray:
    """``(T,)`` frames since the last voice-active frame (0 on one; -1 before the first)."""
    index = np.arange(len(vad))
    last = np.maximum.accumulate(np.where(vad, index, -1))
    return np.where(last >= 0, index - last, -1)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--tracker", help="trainable tracker scored on the training task's validation set")
    source.add_argument("--results", type=Path, nargs="+", help="results files with per-frame estimates (pooled)")
    p.add_argument("--weights", help="weights file (default: the shipped one)")
    p.add_argument("--task", default="sim-train")
    p.add_argument("--librispeech")
    p.add_argument("--holds", default="6,11,16,21,26,31", help="comma-separated frame counts")
    args = p.parse_args(argv)

    from doabench import hold_in_silences
    from doabench.metrics import score_frames

    if args.results is not None:
        name, outputs, truths, vads, valids, planar = _from_results(args.results)
    else:
        name = f"{args.tracker} on the {args.task} validation set"
        outputs, truths, vads, valids, planar = _from_validation(args)

    def errors(directions: list[np.ndarray]) -> np.ndarray:
        # doabench run's scoring: invalid truth left out, planar arrays folded
        return np.concatenate([score_frames(d, t, v, ok, planar).errors
                               for d, t, v, ok in zip(directions, truths, vads, valids)])

    def rms(e: np.ndarray) -> float:
        return float(np.sqrt(np.mean(e**2))) if e.size else float("nan")

    e = errors(outputs)
    # counted over the whole sequence (an invalid frame does not end a silence), then scored frames only
    since = np.concatenate([frames_since_voice(v)[np.ones(len(v), bool) if ok is None else np.asarray(ok, bool)]
                            for v, ok in zip(vads, valids)])
    total = float(np.sum(e**2))
    print(f"{name} ({len(vads)} trajectories, {e.size} frames): "
          f"all {rms(e):.2f} deg, non-silent {rms(e[since == 0]):.2f} deg")
    print("| frames since voice | frames | RMSAE (deg) | share of the squared error |")
    print("|---|---|---|---|")
    rows = [("0 (voice-active)", since == 0)]
    rows += [(f"{lo}-{hi - 1}" if hi else f"{lo} and more", (since >= lo) & ((since < hi) if hi else True))
             for lo, hi in BUCKETS]
    rows.append(("before the first voice", since < 0))
    rows.append(("after the first voice (all but the row above)", since >= 0))
    for label, mask in rows:
        print(f"| {label} | {int(mask.sum()):,} | {rms(e[mask]):.2f} | {np.sum(e[mask] ** 2) / total:.2f} |")
    for hold in (int(h) for h in args.holds.split(",") if h.strip()):
        held = [hold_in_silences(d, v, hold) for d, v in zip(outputs, vads)]
        print(f"hold after {hold} silent frames: all {rms(errors(held)):.2f} deg")
    return 0


def _unit(a) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def _from_results(paths: list[Path]) -> tuple[str, list, list, list, list, bool]:
    import json

    names, frames, planar = [], [], set()
    for path in paths:
        r = json.loads(path.read_text())
        if not r.get("frames"):
            raise SystemExit(f"error: {path} has no per-frame estimates (written with --no-frames?)")
        frames += r["frames"]
        planar.add(bool((r.get("scoring") or {}).get("planar_fold")))
        names.append(f"{r['tracker']['id']} on {r['task']['id']} v{r['task']['version']}")
    if len(planar) > 1:
        raise SystemExit("error: the results files mix planar and non-planar arrays; score them apart")
    name = names[0] if len(names) == 1 else f"{names[0]} and {len(names) - 1} more results files"
    return (name, [_unit(f["estimates"]) for f in frames], [_unit(f["truth"]) for f in frames],
            [np.asarray(f["vad"], bool) for f in frames], [f.get("valid") for f in frames], planar.pop())


def _from_validation(args: argparse.Namespace) -> tuple[list, list, list, list, bool]:
    from doabench.training.recipes import get_recipe
    from doabench.training.trainer import Trainer, TrainOptions

    torch.set_num_threads(1)
    options = {"hold": "off"} | ({"weights": args.weights} if args.weights else {})
    with tempfile.TemporaryDirectory() as out:
        trainer = Trainer(TrainOptions(tracker=args.tracker, out=Path(out), recipe=get_recipe("paper"), task=args.task,
                                       progress=False, librispeech=args.librispeech, tracker_options=options),
                          log=lambda m: None)
        val = trainer.prepare_validation()
    trainer.network.eval()
    outputs, truths, vads = [], [], []
    with torch.no_grad():
        for x, truth, vad in val:
            y = trainer.forward(x, truth)
            y = y / y.norm(dim=-1, keepdim=True).clamp_min(1e-12)
            outputs += list(y.double().numpy())
            truths += list(truth.double().numpy())
            vads += list(vad.numpy().astype(bool))
    from doabench.arrays import get_array

    return outputs, truths, vads, [None] * len(vads), get_array(trainer.spec.array).planar


if __name__ == "__main__":
    raise SystemExit(main())
