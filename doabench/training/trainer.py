"""The training loop shared by every learned tracker (see :mod:`.protocol`).

Per epoch: the curriculum phase sets SNR range, batch size and learning rate; items come seeded
from :mod:`.epoch_data`; features are computed in torch from each batch; the loss is the MSE between
the network output ``(B, T, 3)`` and the true unit vectors of every frame (section IV-C; a recipe may
add a frame-difference term, :mod:`.losses`); then the
fixed validation set is scored (:mod:`.validation`: pooled RMSAE over all and over voice-active
frames), and the checkpoint (:mod:`.run_state`), ``log.csv`` and ``loss.png`` (:mod:`.run_log`) in
the run folder are rewritten atomically. :mod:`.precision` decides the device arithmetic.
"""
from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import torch

from doabench.envs.spec import TaskSpec
from doabench.errors import ConfigError, InputError
from doabench.files import exclusive_lock, write_json
from doabench.training import checkpoint as ckpt
from doabench.training import run_state
from doabench.training.epoch_data import (EpochData, FeatureFn, available_cores, default_features,
                                          default_workers)
from doabench.training.losses import tracking_loss
from doabench.training.pipeline import DEFAULT_CACHE_ROOT
from doabench.training.precision import PrecisionPolicy, cpu_has_native_bf16, resume_precision, training_device
from doabench.training.progress import EpochProgress, loader_length
from doabench.training.protocol import check_trainable, training_defaults, training_observations
from doabench.training.recipes import Recipe
from doabench.training.run_log import CSV_COLUMNS, plot_history, write_log
from doabench.training.validation import ValidationScores

# Names other modules, scripts and benchmarks import from here.
__all__ = ["CSV_COLUMNS", "LOCK_NAME", "TrainOptions", "Trainer", "available_cores", "cpu_has_native_bf16",
           "default_workers", "plot_history", "resume_precision", "write_log"]

# The run folder's lock file (removed when the run ends; a stale one is taken over).
LOCK_NAME = ".lock"


@dataclass
class TrainOptions:
    """What ``doabench train`` passes to :class:`Trainer`."""

    tracker: str
    out: Path
    recipe: Recipe
    task: str | TaskSpec = "sim-train"  # an id, or the spec resolved where it was typed
    librispeech: str | None = None
    cache_root: Path = DEFAULT_CACHE_ROOT
    simulator: str = "builtin"
    resume: bool = False
    threads: int | None = None
    progress: bool = True
    max_epochs: int | None = None  # stop after this many epochs in this invocation
    min_cache: int = 1             # wait for at least this many cached training trajectories
    dataset: Path | None = None    # train from a `doabench make-dataset` file instead
    epochs: int | None = None      # on --resume: a new epoch count (None keeps the run's)
    # recipe options given explicitly (flags of recipes.RECIPE_OPTIONS): on --resume each must
    # agree with the run's own recipe, which the run keeps
    recipe_options: tuple[str, ...] = ()
    tracker_options: dict[str, Any] = field(default_factory=dict)
    precision: str = "auto"        # auto: bf16 autocast where the CPU has native bf16 (or on CUDA), else fp32
    compile: bool = False          # torch.compile the network's training forward (channels-last 3D maps)
    workers: int | None = None     # DataLoader workers; None: the recipe's, capped at the free cores
    device: str = "cpu"            # where the network trains (cuda: also simulation when workers == 0)
    # a new run's starting point: a trained tracker of the same model (another map resolution
    # where the model carries its weights over), built with warm_start_options
    warm_start: str | None = None
    warm_start_options: dict[str, Any] = field(default_factory=dict)


def _set_threads(threads: int | None, device: torch.device, workers: int) -> None:
    if threads:
        torch.set_num_threads(int(threads))
    elif device.type == "cpu" and workers > 0:
        torch.set_num_threads(1)  # one thread per process: the workers use the other cores


class Trainer:
    """Train ``options.tracker`` with ``options.recipe``; ``run()`` returns the epoch history.

    ``tracker``, ``feature_fn``, ``train_cache`` and ``val_cache`` may be injected (tests, tools);
    by default they come from the tracker id, :class:`~doabench.features.FeatureExtractor` and
    the caches of :mod:`.pipeline`.
    """

    # -- data-parallel hooks (set by doabench.training.distributed; None in a one-process run) -----
    dist: Any = None

    @property
    def is_writer(self) -> bool:
        """Whether this process writes the run folder: always in one process, rank 0 in data-parallel runs."""
        return self.dist is None or self.dist.rank == 0
    # -- end of data-parallel hooks ---------------------------------------------------------------

    def __init__(self, options: TrainOptions, tracker: Any = None, feature_fn: FeatureFn | None = None,
                 train_cache: Path | None = None, val_cache: Path | None = None,
                 log: Callable[[str], None] = print) -> None:
        from doabench.envs.registry import get_task_spec
        from doabench.trackers.registry import make_tracker

        self.options, self.log = options, log
        self.out = Path(options.out)
        self.spec = get_task_spec(options.task)
        self.saved, self._saved_stamp = run_state.load_saved_run(self.out, options.resume)
        recipe = options.recipe
        if self.saved is not None:  # the run keeps its recipe; only the epoch count may change
            recipe = run_state.resumed_recipe(self.saved, options.recipe, options.recipe_options, options.epochs,
                                              self.out)
        self.device = training_device(options.device)
        saved_precision, started_in = run_state.saved_precisions(self.saved)
        precision, note = resume_precision(saved_precision, options.precision, self.device, started_in=started_in)
        if note:
            log(note)
        torch.manual_seed(recipe.seed)  # network initialisation
        built = tracker if tracker is not None else make_tracker(options.tracker, **options.tracker_options)
        self.tracker = check_trainable(built, options.tracker)
        if self.saved is not None:
            run_state.check_same_task(self.saved, self.spec, self.out)
        # What the run starts from: recorded in the checkpoint and in exported weights files.
        self.initial_weights: dict[str, Any] | None
        if options.warm_start is not None:
            self.initial_weights = run_state.warm_start(self.saved, self.tracker, options.warm_start,
                                                        options.warm_start_options, self.out, log)
        else:
            self.initial_weights = run_state.initial_weights(self.saved, self.tracker, options.tracker, log)
        if recipe.t60 is None and "t60" in (defaults := training_defaults(self.tracker)):
            recipe = recipe.replace(t60=tuple(defaults["t60"]))
        self.recipe = recipe
        self.network: torch.nn.Module = self.tracker.network
        if self.saved is not None:
            run_state.check_same_network(self.saved, self.network, options.tracker, self.out)
            run_state.check_same_observations(self.saved, training_observations(self.tracker), self.out)
        self.policy = PrecisionPolicy.for_network(self.network, self.device, precision, options.compile)
        self.policy.place(self.network)
        self.train_forward = torch.compile(self.network) if options.compile else self.network
        self.frame_spec = self.tracker.frame_spec
        self.feature_fn = feature_fn or default_features(self.tracker, self.spec)
        self.optimizer = torch.optim.Adam(self.network.parameters(), lr=recipe.phases[0].lr)
        requested = recipe.num_workers if options.workers is None else options.workers
        workers = default_workers(requested) if options.workers is None else max(0, int(options.workers))
        self.data = EpochData(options, self.spec, recipe, self.frame_spec, self.tracker, self.item_input, workers,
                              self.device, train_cache, val_cache, log)
        _set_threads(options.threads, self.device, workers)
        # Validation also scores the outputs under the tracker's hold rule (doabench.hold_in_silences;
        # None: the tracker never holds), the way `doabench run` will use the weights, and a new run
        # keeps the epoch that is best by that score (run_state.best_by: older runs keep theirs).
        self.hold_frames: int | None = getattr(self.tracker, "hold_frames", None)
        self.best_by = run_state.best_by(self.saved)

    @property
    def precision(self) -> str:
        """``bf16`` or ``fp32``: the arithmetic of this invocation's forward passes."""
        return self.policy.precision

    @property
    def workers(self) -> int:
        """DataLoader worker processes (data-parallel runs set their share per rank)."""
        return self.data.workers

    @workers.setter
    def workers(self, n: int) -> None:
        self.data.workers = n

    def _epoch_items(self, epoch: int, snr: tuple[float, float]):
        """Epoch ``epoch``'s items and cached-trajectory count (benchmarks time them)."""
        return self.data.epoch_items(epoch, snr)

    # -- one step, validation ------------------------------------------------------------------
    def network_input(self, batch: Mapping[str, torch.Tensor]) -> torch.Tensor:
        with torch.no_grad():
            if "input" in batch:  # computed by the data workers
                return batch["input"]
            if "features" in batch:  # stored features (dataset file)
                return self.tracker.network_input(dict(batch["features"]))
            feats = dict(self.feature_fn(batch["audio"], batch["sample_vad"]))
            return self.tracker.network_input(feats)

    def item_input(self, audio: torch.Tensor, sample_vad: torch.Tensor) -> torch.Tensor:
        """The network input of one item (``audio`` ``(M, L)``, ``sample_vad`` ``(L,)``), without its batch axis."""
        dev = self.data.data_device()
        with torch.no_grad():
            feats = self.feature_fn(audio[None].to(dev), sample_vad[None].to(dev))
            return self.tracker.network_input(dict(feats))[0]

    def forward(self, x: torch.Tensor, truth: torch.Tensor, network: Callable | None = None) -> torch.Tensor:
        with self.policy.autocast():  # bf16 activations, float32 master weights and loss
            y = (self.network if network is None else network)(x).float()
        if y.shape != truth.shape:
            raise ConfigError(f"tracker {self.options.tracker!r}: network output {tuple(y.shape)} does not match "
                              f"the truth {tuple(truth.shape)} (B, T, 3)")
        return y

    def train_step(self, batch: Mapping[str, torch.Tensor]) -> float:
        """One Adam step on ``batch``; returns the loss before the step."""
        self.network.train()
        x = self.policy.to_device(self.network_input(batch))
        truth = batch["truth"].to(self.device)
        loss = tracking_loss(self.forward(x, truth, self.train_forward), truth, self.recipe.delta_loss)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        return float(loss.detach())

    def prepare_validation(self) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
        """Network inputs, truth and frame VAD of the fixed validation set (computed once)."""
        return [(self.network_input(b), b["truth"], b["vad"]) for b in self.data.validation_loader()]

    @torch.no_grad()
    def validate(self, val: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]) -> dict[str, float]:
        """The validation scores of the current weights (:class:`.validation.ValidationScores`)."""
        from doabench.arrays import get_array

        self.network.eval()
        scores = ValidationScores(self.hold_frames, bool(get_array(self.spec.array).planar))
        for x, truth, vad in val:
            x, truth = self.policy.to_device(x), truth.to(self.device)
            scores.add(self.forward(x, truth).cpu(), truth.cpu(), vad)  # (B, T, 3)
        return scores.metrics()

    # -- the loop ---------------------------------------------------------------------------------
    def run(self) -> list[dict[str, Any]]:
        """Train; returns the epoch history. One process at a time writes a run folder: a second
        ``train --out`` of the same folder gets one line naming the first one's pid."""
        if self.options.dataset is None and self.recipe.data == "cache":
            self.data.train_cache()  # a missing cache is an error before the run folder is written
        if not self.is_writer:
            return self._run()
        with exclusive_lock(self.out / LOCK_NAME, f"the training run {self.out}"):
            if run_state.checkpoint_stamp(self.out / ckpt.LATEST) != self._saved_stamp:
                raise InputError(f"another process wrote {self.out / ckpt.LATEST} while this one started; "
                                 "run the command again to continue from it")
            return self._run()

    def _run(self) -> list[dict[str, Any]]:
        self.out.mkdir(parents=True, exist_ok=True)
        progress = run_state.RunProgress()
        if self.saved is not None:
            run_state.restore(self.saved, self.network, self.optimizer)
            progress = run_state.RunProgress.from_saved(self.saved)
            self.log(f"resuming {self.out} after epoch {progress.epoch}")
        if self.is_writer:  # data-parallel hook
            write_json(self.out / "config.json", self.describe())
        val = self.prepare_validation()
        if self.initial_weights is not None and "validation" not in self.initial_weights:
            # the starting point on this run's validation set, to compare the epochs with
            self.initial_weights["validation"] = start_metrics = self.validate(val)
            self.log(f"starting weights: val loss {start_metrics['val_loss']:.4f}, val RMSAE "
                     f"{start_metrics['val_rmsae_all']:.2f} deg (non-silent {start_metrics['val_rmsae_nonsilent']:.2f})")
        ran = 0
        # where the run stands, for the message of an interrupted run: epochs kept, and within an epoch the
        # batches done of how many since when
        self.stop_state: dict[str, Any] = {"kept": progress.epoch, "epoch": None}
        for epoch in range(progress.epoch, self.recipe.epochs):
            if self.options.max_epochs is not None and ran >= self.options.max_epochs:
                break
            t0 = time.perf_counter()
            # Kept in case this epoch's weights are not better: they are the only copy of the best.
            weights_before = copy.deepcopy(self.network.state_dict()) if progress.latest_is_best else None
            phase = self.recipe.phase(epoch)
            for group in self.optimizer.param_groups:
                group["lr"] = phase.lr
            items, n_cache = self.data.epoch_items(epoch, phase.snr)
            if self.dist is None:
                loader = self.data.loader(items, phase.batch_size)
            else:  # data-parallel hook: this rank's share of each global batch
                loader = self.dist.loader(self, items, phase.batch_size)
            losses = []
            self.stop_state.update(epoch=epoch + 1, since=t0, batches=0, of=loader_length(loader))
            with EpochProgress(loader_length(loader), f"epoch {epoch + 1}/{self.recipe.epochs}",
                               self.options.progress) as bar:
                for batch in loader:
                    losses.append(self.train_step(batch))
                    self.stop_state["batches"] += 1
                    bar.step(float(np.mean(losses[-20:])))
            metrics = self.validate(val)
            epoch_s = time.perf_counter() - t0
            progress.compute_s += epoch_s
            progress.trajectories_seen += len(items)
            row = {"epoch": epoch + 1, "phase_snr": f"{phase.snr[0]:g}-{phase.snr[1]:g}", "precision": self.precision,
                   "batch_size": phase.batch_size, "lr": phase.lr, "train_loss": float(np.mean(losses)),
                   **metrics, "n_cache": n_cache, "trajectories_seen": progress.trajectories_seen,
                   "epoch_s": round(epoch_s, 1), "compute_s": round(progress.compute_s, 1),
                   "trajectories_per_s": round(len(items) / epoch_s, 3)}
            progress.add_epoch(row, metrics[self.best_by], weights_before)
            if self.is_writer:  # data-parallel hook: rank 0 alone writes the run folder
                ckpt.save_checkpoint(self.out / ckpt.LATEST, self._checkpoint_state(progress))
                write_log(self.out / "log.csv", progress.history)
                plot_history(self.out / "loss.png", progress.history, self.options.tracker)
            self.stop_state.update(kept=epoch + 1, epoch=None)
            self.log(f"epoch {epoch + 1}: train loss {row['train_loss']:.4f}, val loss {metrics['val_loss']:.4f}, "
                     f"val RMSAE {metrics['val_rmsae_all']:.2f} deg (non-silent {metrics['val_rmsae_nonsilent']:.2f}, "
                     f"held {metrics['val_rmsae_held']:.2f}), {epoch_s:.0f} s")
            ran += 1
        return progress.history

    def _checkpoint_state(self, progress: run_state.RunProgress) -> dict[str, Any]:
        run = {"recipe": self.recipe.to_dict(), "tracker": self.options.tracker, "task": self.spec.id,
               "task_version": self.spec.version, "initial_weights": self.initial_weights,
               "tracker_options": run_state.build_options(self.options.tracker_options),
               "observations": training_observations(self.tracker).to_dict()}
        setup = {"threads": torch.get_num_threads(), "precision": self.precision, "device": str(self.device),
                 "workers": self.workers, "compiled": bool(self.options.compile)}
        return run_state.checkpoint_state(progress, self.network, self.optimizer, run, setup, self.best_by)

    def stop_note(self) -> str:
        """What an interrupted run kept and lost (the checkpoint is written at epoch ends only)."""
        state = getattr(self, "stop_state", None) or {"kept": int((self.saved or {}).get("epoch", 0)), "epoch": None}
        kept = (f"the checkpoint after epoch {state['kept']} is kept in {self.out}" if state["kept"]
                else "no epoch had finished, so no checkpoint was written")
        if state.get("epoch") is None:
            return kept
        minutes = (time.perf_counter() - state["since"]) / 60
        where = (f"after {state['batches']} of {state['of']} batches" if state.get("of")
                 else f"after {state['batches']} batches")
        return (f"{kept}; epoch {state['epoch']} was stopped {where} ({minutes:.1f} min of work, which a resume "
                "does again from the epoch's start)")

    def describe(self) -> dict[str, Any]:
        train_cache = self.data.train_cache_dir
        return {"tracker": self.options.tracker, "task": self.spec.id, "task_version": self.spec.version,
                "recipe": self.recipe.to_dict(), "frame": self.frame_spec.to_dict(),
                "features": list(self.tracker.features),
                "resolution": None if self.tracker.resolution is None else list(self.tracker.resolution),
                "dataset": None if self.options.dataset is None else str(self.options.dataset),
                "train_cache": None if train_cache is None else str(train_cache),
                "initial_weights": None if self.initial_weights is None else {
                    k: self.initial_weights.get(k) for k in ("weights", "sha256")},
                "threads": torch.get_num_threads(), "torch": torch.__version__, "precision": self.precision,
                "compile": bool(self.options.compile), "workers": self.workers, "device": str(self.device),
                "hold_frames": self.hold_frames, "best_by": self.best_by}
