"""``doabench train --tracker cross3d:8x16 --out runs/NAME``: train a learned tracker.

The paper's recipe by default (``--preset paper``: trajectories simulated on the fly); ``--preset
cpu`` trains from a cache of simulated noise-free trajectories (build it with ``--build-cache``,
possibly in a second process while training runs). See docs/training.md.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from doabench.cli.common import add_tracker_options, use_threads


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("train", help="train a learned tracker (Cross3D, 1D/2D CNNs, SELDnet)",
                       description="Train a learned tracker with the Cross3D paper's recipe (--preset paper) or the "
                                   "CPU preset (--preset cpu, cached trajectories). Checkpoints every epoch; "
                                   "--resume continues exactly, with the run's own recipe: a recipe option given with "
                                   "--resume must agree with it (only --epochs may change). See docs/training.md.")
    add_tracker_options(p, help="learned tracker to train: cross3d:16x32 (any resolution), max-cnn1d, gcc-cnn1d, "
                                "spec-cnn2d, seldnet, or a package.module:Class plug-in with a trainable network")
    p.add_argument("--task", default="sim-train", help="training distribution (default: sim-train)")
    p.add_argument("--preset", choices=["paper", "cpu", "finetune"],
                   help="training recipe (default: paper); finetune: 10 epochs at the paper's second phase "
                        "(lr 3e-5, then 1e-5) from the tracker's trained weights, for a changed training task")
    p.add_argument("--epochs", type=int, help="number of epochs (default: the preset's)")
    p.add_argument("--epoch-size", type=int, help="trajectories per epoch (default: the preset's)")
    p.add_argument("--cache-size", type=int, help="cached training trajectories (cpu preset)")
    p.add_argument("--val-trajectories", type=int, help="validation trajectories (default: the preset's)")
    p.add_argument("--switch-epoch", type=int,
                   help="epoch at which the curriculum's second phase starts (paper: 20; cpu: half the epochs)")
    p.add_argument("--lr", metavar="LR[,LR...]",
                   help="learning rate of each curriculum phase, in order (paper: 1e-4,1e-5); one value sets "
                        "every phase")
    p.add_argument("--delta-loss", type=float, metavar="WEIGHT",
                   help="add WEIGHT x the MSE of the output's frame-to-frame change to the paper's MSE loss "
                        "(beyond the paper; default 0: the paper's loss)")
    p.add_argument("--seed", type=int, help="run seed (network init and item seeds; default 0)")
    p.add_argument("--workers", type=int,
                   help="DataLoader worker processes that simulate and extract features (default: the preset's, "
                        "at most the cores but one)")
    p.add_argument("--precision", choices=["auto", "bf16", "fp32"], default="auto",
                   help="auto (default): bf16 autocast with float32 master weights where the CPU has native bf16 "
                        "(AVX-512 BF16/AMX) or on CUDA, else float32")
    p.add_argument("--compile", action=argparse.BooleanOptionalAction, default=None,
                   help="torch.compile the network (default: on for the presets that simulate on the fly, paper and finetune; about 1-2 minutes of "
                        "compilation per batch shape, then a faster step)")
    p.add_argument("--device", default="cpu", help="device the network trains on: cpu (default) or cuda")
    p.add_argument("--warm-start", metavar="TRACKER",
                   help="start a new run from this trained tracker's weights (same model and observations; "
                        "Cross3D also from a coarser map, e.g. --tracker cross3d:32x64 --warm-start cross3d:16x32 "
                        "--warm-start-opt weights=moving-long)")
    p.add_argument("--warm-start-opt", action="append", default=[], metavar="KEY=VALUE",
                   help="option of the --warm-start tracker (repeatable), e.g. weights=moving-long")
    p.add_argument("--out", required=True, help="run folder: checkpoints, log.csv, loss.png")
    p.add_argument("--resume", action="store_true", help="continue the run in --out")
    p.add_argument("--librispeech", help="LibriSpeech root holding train-clean-100 (default: $DOABENCH_LIBRISPEECH)")
    p.add_argument("--backend", default="builtin",
                   help="room simulator: builtin, pyroomacoustics, pyroomacoustics-full, torchrir or gpurir")
    p.add_argument("--cache-root", default="runs/cache", help="folder of trajectory caches (default: runs/cache)")
    p.add_argument("--dataset", metavar="FILE",
                   help="train from a dataset file made by `doabench make-dataset` (stored features) instead; one "
                        "made from a benchmark task (not a training task such as sim-train) is used with a warning")
    p.add_argument("--build-cache", action="store_true",
                   help="only simulate the missing validation and training cache items, then exit; the cpu "
                        "preset needs this step first (it can run in a second process while training uses "
                        "what is there, see --min-cache)")
    p.add_argument("--min-cache", type=int, default=1,
                   help="wait until this many training trajectories are cached before each epoch")
    p.add_argument("--threads", type=int, help="torch CPU threads")
    p.add_argument("--max-epochs", type=int, help="stop after this many epochs in this invocation")
    p.add_argument("--export", metavar="FILE", help="export the run's weights to FILE (.safetensors) and exit")
    p.add_argument("--compact", action="store_true",
                   help="rewrite the run's checkpoint for committing (Adam moments and best weights in bfloat16, "
                        "about 40%% smaller) and exit; a resume from it continues with rounded moments")
    p.add_argument("--export-from", choices=["best", "latest"], default="best", help="checkpoint to export")
    p.add_argument("--export-dtype", choices=["float32", "float16"], default="float32",
                   help="precision of the exported weights (float16 halves the file)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=main)


def given_recipe_options(args: argparse.Namespace) -> tuple[str, ...]:
    """The recipe options (:data:`~doabench.training.recipes.RECIPE_OPTIONS`) given on the command
    line: a resumed run checks them against its own recipe."""
    from doabench.training.recipes import RECIPE_OPTIONS

    return tuple(flag for flag in RECIPE_OPTIONS if getattr(args, flag[2:].replace("-", "_")) is not None)


def build_recipe(args: argparse.Namespace):
    from dataclasses import replace

    from doabench.errors import ConfigError
    from doabench.training.recipes import get_recipe

    preset = args.preset or "paper"
    recipe = get_recipe(preset)
    changes: dict[str, Any] = {"seed": 0 if args.seed is None else args.seed}
    for arg, key in (("epochs", "epochs"), ("epoch_size", "trajectories_per_epoch"), ("cache_size", "cache_size"),
                     ("val_trajectories", "val_trajectories"), ("delta_loss", "delta_loss")):
        if getattr(args, arg) is not None:
            changes[key] = getattr(args, arg)
    if args.switch_epoch is not None:
        if len(recipe.phases) < 2 or args.switch_epoch < 1:
            raise ConfigError("--switch-epoch needs a two-phase recipe and an epoch >= 1")
        changes["phases"] = (recipe.phases[0], replace(recipe.phases[1], start_epoch=args.switch_epoch))
    elif preset == "cpu" and args.epochs is not None:
        changes["phases"] = (recipe.phases[0], replace(recipe.phases[1], start_epoch=max(1, args.epochs // 2)))
    if args.lr is not None:
        phases = changes.get("phases", recipe.phases)
        rates = parse_learning_rates(args.lr, len(phases))
        changes["phases"] = tuple(replace(phase, lr=lr) for phase, lr in zip(phases, rates))
    return recipe.replace(**changes)


def parse_learning_rates(text: str, n_phases: int) -> list[float]:
    """``--lr`` text -> one learning rate per curriculum phase (one value is repeated)."""
    from doabench.errors import ConfigError

    try:
        rates = [float(v) for v in text.split(",")]
    except ValueError:
        raise ConfigError(f"--lr takes comma-separated numbers, got {text!r}") from None
    if len(rates) == 1:
        rates *= n_phases
    if len(rates) != n_phases or not all(r > 0 and r != float("inf") for r in rates):
        raise ConfigError(f"--lr needs one positive learning rate or {n_phases} (one per curriculum phase), "
                          f"got {text!r}")
    return rates


def benchmark_dataset_warning(path: Path) -> str | None:
    """One warning line when the dataset file ``path`` holds episodes of a benchmark task (one that
    scores trackers, :func:`~doabench.envs.spec.is_training_task`), None for a training task's: a
    model trained on a task's episodes has seen its test data there, so its scores on it measure
    memory, not tracking. An unreadable file is the reader's one-line error."""
    from doabench.datasets import DatasetFile
    from doabench.envs.spec import is_training_task

    with DatasetFile(path) as dataset:
        task = dataset.task_spec or {"id": dataset.task_id}
    if is_training_task(task):
        return None
    task_id = task.get("id") or "its task"
    return (f"doabench train: warning: {path} holds episodes of {task_id}, a benchmark task: training on a "
            f"benchmark task's episodes makes this model's scores on {task_id} meaningless (make the dataset "
            "from a training task, e.g. --task sim-train)")


def main(args: argparse.Namespace) -> int:
    from doabench.trackers.registry import make_tracker, parse_options
    from doabench.training.protocol import check_trainable

    from doabench.cli.common import command_line, set_interrupt_note

    options = parse_options(args.tracker_opt)
    use_threads(args)
    if args.compact:
        from doabench.files import exclusive_lock
        from doabench.training import checkpoint as ckpt
        from doabench.training.trainer import LOCK_NAME

        if not (Path(args.out) / ckpt.LATEST).is_file():
            before, after = ckpt.compact_checkpoint(Path(args.out) / ckpt.LATEST)  # its one-line error
        with exclusive_lock(Path(args.out) / LOCK_NAME, f"the training run {args.out}"):  # not under a running train
            before, after = ckpt.compact_checkpoint(Path(args.out) / ckpt.LATEST)
        print(f"compacted {Path(args.out) / ckpt.LATEST}: {before / 1e6:.1f} -> {after / 1e6:.1f} MB")
        return 0
    if args.export:
        from doabench.training.export import export_weights

        path = export_weights(args.out, args.export, args.export_from, tracker_id=args.tracker,
                              dtype=args.export_dtype)
        print(f"wrote {path}")
        return 0
    from doabench.envs.registry import get_task_spec

    task = get_task_spec(args.task)  # resolved once, here: the run and its cache take the spec
    checked = check_trainable(make_tracker(args.tracker, **options), args.tracker)  # fail fast, one line
    if args.dataset and (warning := benchmark_dataset_warning(Path(args.dataset))):
        print(warning, file=sys.stderr, flush=True)
    from doabench.training.trainer import TrainOptions, Trainer

    recipe = build_recipe(args)
    opts = TrainOptions(tracker=args.tracker, out=Path(args.out), recipe=recipe, task=task,
                        librispeech=args.librispeech, cache_root=Path(args.cache_root), simulator=args.backend,
                        resume=args.resume, threads=args.threads, progress=not args.quiet,
                        max_epochs=args.max_epochs, min_cache=args.min_cache, tracker_options=options,
                        dataset=Path(args.dataset) if args.dataset else None, epochs=args.epochs,
                        recipe_options=given_recipe_options(args), precision=args.precision,
                        workers=args.workers, device=args.device, warm_start=args.warm_start,
                        warm_start_options=parse_options(args.warm_start_opt),
                        compile=recipe.data == "simulate" if args.compile is None else args.compile)
    if args.build_cache:
        from doabench.training.distributed import is_distributed_launch

        if is_distributed_launch():
            from doabench.errors import ConfigError

            raise ConfigError("--build-cache runs in one process: start it without torchrun")
        from doabench.training.pipeline import ensure_cache
        from doabench.training.protocol import training_defaults

        recipe = opts.recipe
        if recipe.t60 is None and "t60" in (d := training_defaults(checked)):
            recipe = recipe.replace(t60=tuple(d["t60"]))
        set_interrupt_note(args, lambda: f"the trajectories cached so far are kept in {opts.cache_root}; continue "
                                         f"with the same command: {command_line(args)}")
        log = lambda m: print(m, flush=True)  # noqa: E731
        ensure_cache(opts.cache_root, task, recipe, "val", recipe.val_trajectories, args.librispeech, args.backend, log)
        if recipe.data == "cache":
            ensure_cache(opts.cache_root, task, recipe, "train", recipe.cache_size, args.librispeech, args.backend, log)
        return 0
    from doabench.training.distributed import is_distributed_launch, run_distributed

    if is_distributed_launch():  # torchrun --nproc-per-node N -m doabench train ... (docs/scale-out.md)
        history = run_distributed(opts, log=lambda m: print(m, flush=True))  # [] on ranks > 0
    else:
        trainer = Trainer(opts, log=lambda m: print(m, flush=True))
        set_interrupt_note(args, lambda: f"{trainer.stop_note()}; resume with: {command_line(args, ['--resume'])}")
        history = trainer.run()
    if history:
        last = history[-1]
        print(f"trained {last['epoch']} epochs ({last['trajectories_seen']} trajectories, {last['compute_s']:.0f} s); "
              f"validation RMSAE {last['val_rmsae_all']:.2f} deg; run folder {args.out}")
    return 0
