"""Maintainers: the terms of the training loss on a trained model's validation outputs (to weigh --delta-loss).

Scores a tracker's weights on the fixed validation set of a training task, as `doabench train`
builds it, and prints the paper's MSE, the frame-difference MSE (:mod:`doabench.training.losses`)
and the truth's own mean squared change per frame. `--delta-loss W` adds W times the second to the
first, so their ratio says what a weight does to the loss at the start of a finetune. E.g.

    python scripts/loss_terms.py --tracker cross3d:16x32 \\
        --weights baselines/weights/cross3d-16x32-moving.safetensors --task sim-train-moving
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import torch

from doabench.training.losses import frame_difference_mse
from doabench.training.recipes import get_recipe
from doabench.training.trainer import TrainOptions, Trainer


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tracker", required=True, help="learned tracker id, e.g. cross3d:16x32")
    ap.add_argument("--weights", required=True, help="weights file to score")
    ap.add_argument("--task", default="sim-train", help="training task whose validation set is used")
    ap.add_argument("--librispeech", help="LibriSpeech root (default: $DOABENCH_LIBRISPEECH)")
    ap.add_argument("--cache-root", default="runs/cache", help="folder of trajectory caches (default: runs/cache)")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as out:
        opts = TrainOptions(tracker=args.tracker, out=Path(out) / "run", recipe=get_recipe("finetune"), task=args.task,
                            librispeech=args.librispeech, cache_root=Path(args.cache_root), progress=False,
                            tracker_options={"weights": args.weights}, workers=0)
        trainer = Trainer(opts, log=print)
        mse, delta, change = [], [], []
        for x, truth, _ in trainer.prepare_validation():
            with torch.no_grad():
                y = trainer.forward(trainer.policy.to_device(x), truth)
            mse.append(float(torch.nn.functional.mse_loss(y, truth)))
            delta.append(float(frame_difference_mse(y, truth)))
            change.append(float(truth.diff(dim=1).pow(2).mean()))
    print(f"MSE {np.mean(mse):.4f}, frame-difference MSE {np.mean(delta):.4f} "
          f"(ratio {np.mean(delta) / np.mean(mse):.3f}), truth's squared change per frame {np.mean(change):.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
