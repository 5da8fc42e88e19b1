"""Can a learned tracker fit its training data? Two small measurements for the spectrogram models
(docs/training.md, "The spectrogram models: what was measured").

* ``--batch``: one fixed batch of 5 anechoic 5 s trajectories (T60 0, SNR 30 dB, sim-train v3 scenes),
  N Adam steps on it; prints the loss every N/10 steps and the output's standard deviation after.
* otherwise: 20 such trajectories, the same ones every epoch, N epochs of 4 batches; prints the
  training loss and the validation RMSAE (10 other trajectories) per epoch.

Each with the model's own initialisation (``default``; spec-cnn2d's own is Kaiming's since it measured
better here) or Kaiming's for its (P)ReLUs (``kaiming``); ``--phase relative`` reads the phases
relative to the first microphone's (the tracker option ``phase``); two changes to spec-cnn2d's
network that are not the paper's, to see what holds its fit back: ``--variant bn`` (batch
normalisation before each convolution's PReLU) and ``--variant small-output`` (the output
convolution's initial weights times 0.01, so the tanh starts unsaturated)::

    .venv/bin/python benchmarks/probe_fit.py seldnet default 1e-3 60 --batch --librispeech PATH
    .venv/bin/python benchmarks/probe_fit.py spec-cnn2d kaiming 1e-4 30 --librispeech PATH
    .venv/bin/python benchmarks/probe_fit.py spec-cnn2d default 1e-4 30 --phase relative --librispeech PATH
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import torch

from doabench.envs.registry import get_task_spec
from doabench.training.pipeline import ensure_cache
from doabench.training.recipes import Phase, get_recipe
from doabench.training.trainer import TrainOptions, Trainer


def kaiming(network: torch.nn.Module) -> None:
    """He initialisation for PReLU (slope 0.25) of every convolution and linear layer, zero biases."""
    with torch.no_grad():
        for m in network.modules():
            if isinstance(m, (torch.nn.Conv1d, torch.nn.Conv2d, torch.nn.Conv3d, torch.nn.Linear)):
                torch.nn.init.kaiming_normal_(m.weight, a=0.25, nonlinearity="leaky_relu")
                if m.bias is not None:
                    m.bias.zero_()


def apply_variant(network: torch.nn.Module, variant: str) -> None:
    """spec-cnn2d's network changed as ``variant`` says (``paper``: unchanged)."""
    if variant == "bn":
        for i, act in enumerate(network.acts):
            network.acts[i] = torch.nn.Sequential(torch.nn.BatchNorm2d(network.channels), act)
    elif variant == "small-output":
        with torch.no_grad():
            network.output.conv.weight.mul_(0.01)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("tracker")
    ap.add_argument("init", choices=["default", "kaiming"])
    ap.add_argument("lr", type=float)
    ap.add_argument("n", type=int, help="steps (--batch) or epochs")
    ap.add_argument("--batch", action="store_true", help="fit one fixed batch")
    ap.add_argument("--librispeech", required=True)
    ap.add_argument("--cache-root", default="runs/cache-probe")
    ap.add_argument("--phase", choices=["absolute", "relative"], default="absolute",
                    help="the spectrogram's phase channels (the spectrogram trackers' phase option)")
    ap.add_argument("--variant", choices=["paper", "bn", "small-output"], default="paper",
                    help="spec-cnn2d's network as the paper has it, or changed (see above)")
    args = ap.parse_args()
    recipe = get_recipe("cpu").replace(epochs=1 if args.batch else args.n, trajectories_per_epoch=20, cache_size=20,
                                       val_trajectories=10, t60=(0.0, 0.0), duration_s=5.0,
                                       phases=(Phase(0, (30.0, 30.0), 5, args.lr),))
    cache_root = Path(args.cache_root)
    spec = get_task_spec("sim-train")
    for split, n in (("val", recipe.val_trajectories), ("train", recipe.cache_size)):
        ensure_cache(cache_root, spec, recipe, split, n, args.librispeech, "builtin", print)
    with tempfile.TemporaryDirectory() as out:
        opts = TrainOptions(tracker=args.tracker, out=Path(out), recipe=recipe, task="sim-train",
                            librispeech=args.librispeech, cache_root=cache_root, progress=False,
                            tracker_options={"weights": "random", "phase": args.phase}, workers=0, threads=1,
                            compile=False)
        trainer = Trainer(opts, log=print if not args.batch else (lambda message: None))
        if args.init == "kaiming":
            kaiming(trainer.network)
        if args.variant != "paper":
            if args.tracker != "spec-cnn2d":
                ap.error("--variant changes spec-cnn2d's network only")
            apply_variant(trainer.network, args.variant)
            trainer.optimizer = torch.optim.Adam(trainer.network.parameters(), lr=args.lr)
        if not args.batch:
            trainer.run()
            return
        items, _ = trainer.data.epoch_items(0, (30.0, 30.0))
        batch = next(iter(trainer.data.loader(items, 5)))
        losses = [trainer.train_step(batch) for _ in range(args.n)]
        with torch.no_grad():
            trainer.network.eval()
            y = trainer.forward(trainer.policy.to_device(trainer.network_input(batch)), batch["truth"])
        every = max(1, args.n // 10)
        print(f"{args.tracker} {args.init} lr {args.lr:g}: loss " + " ".join(f"{v:.3f}" for v in losses[::every])
              + f" -> {losses[-1]:.3f}; output std {float(y.std()):.3f}")


if __name__ == "__main__":
    main()
