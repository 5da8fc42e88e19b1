"""The training loop shared by every learned tracker (see :mod:`.protocol`).

Per epoch: the curriculum phase sets SNR range, batch size and learning rate; items come seeded
from :mod:`.data`; features are computed in torch from each batch; the loss is the MSE between the
network output ``(B, T, 3)`` and the true unit vectors of every frame (section IV-C); then the
fixed validation set is scored (pooled RMSAE over all and over voice-active frames), and the
checkpoint, ``log.csv`` and ``loss.png`` in the run folder are rewritten atomically.
"""
from __future__ import annotations

import contextlib
import copy
import csv
import io
import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import torch
from torch.utils.data import DataLoader

from doabench.errors import ConfigError, InputError, NotFoundError
from doabench.results.files import atomic_path, exclusive_lock, write_json, write_text
from doabench.trackers.hold import held_frame_index
from doabench.training import checkpoint as ckpt
from doabench.training.cache import TrajectoryCache
from doabench.training.data import (CachedItems, DatasetItems, NetworkInputs, SimulatedItems, ValidationItems,
                                    collate)
from doabench.training.pipeline import (DEFAULT_CACHE_ROOT, cache_folder, ensure_cache, scene_distribution,
                                        speech_for_split)
from doabench.training.progress import EpochProgress, loader_length
from doabench.training.protocol import check_trainable, feature_options, training_defaults
from doabench.training.recipes import Recipe, resume_conflicts

FeatureFn = Callable[[torch.Tensor, torch.Tensor], Mapping[str, torch.Tensor]]
CSV_COLUMNS = ("epoch", "phase_snr", "batch_size", "lr", "train_loss", "val_loss", "val_rmsae_all",
               "val_rmsae_nonsilent", "val_rmsae_held", "n_cache", "trajectories_seen", "epoch_s", "compute_s",
               "trajectories_per_s")
PRECISIONS = ("auto", "bf16", "fp32")
# The run folder's lock file (removed when the run ends; a stale one is taken over).
LOCK_NAME = ".lock"


@dataclass
class TrainOptions:
    """What ``doabench train`` passes to :class:`Trainer`."""

    tracker: str
    out: Path
    recipe: Recipe
    task: str = "sim-train"
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


def cpu_has_native_bf16() -> bool:
    """True where oneDNN runs bf16 natively (AVX-512 BF16 or AMX): there autocast pays off."""
    try:
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):
        return False


def resolve_precision(precision: str, device: torch.device) -> str:
    if precision not in PRECISIONS:
        raise ConfigError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    if precision == "auto":
        return "bf16" if device.type == "cuda" or cpu_has_native_bf16() else "fp32"
    return precision


def resume_precision(saved: str | None, requested: str, device: torch.device,
                     started_in: str | None = None) -> tuple[str, str | None]:
    """The precision a run trains in, and a note to print when it is not the run's saved one.

    A new run (``saved`` None) resolves ``requested``. A resumed run keeps its precision, except
    that an explicit ``--precision`` wins (autocast only rounds activations: master weights, loss
    and Adam state stay float32, so the checkpoint is the same either way) and that ``auto`` falls
    back to fp32 for a bf16 run resumed on a CPU without native bf16, where autocast is emulated:
    12.8x slower than float32 for a Cross3D 4x8 step on an AVX2-only AMD EPYC (docs/training.md).
    That fallback is the machine's, not the run's: ``started_in`` (the precision of the run's first
    epoch) says which precision the run is, so a bf16 run that went on in fp32 on such a CPU goes
    back to bf16 on the next one that has it (before this rule cross3d-16x32-v3, a bf16 run with
    17 fp32 epochs from AVX2 sessions, resumed in fp32 on an AVX-512 BF16 CPU)."""
    if saved is None:
        return resolve_precision(requested, device), None
    if requested != "auto":
        precision = resolve_precision(requested, device)
        if precision == saved:
            return precision, None
        return precision, f"note: the run trained in {saved} so far; it continues in {precision} (--precision)"
    if "bf16" not in (saved, started_in):
        return saved, None
    if device.type == "cpu" and not cpu_has_native_bf16():
        if saved == "fp32":
            return "fp32", None
        return "fp32", ("note: the run trained in bf16 so far, but this CPU has no native bf16 (autocast would be "
                        "emulated, about 13x slower): it continues in fp32 (--precision bf16 forces bf16)")
    if saved != "bf16":
        return "bf16", ("note: the run started in bf16 and went on in fp32 on a CPU without native bf16; this "
                        "device has it, so it continues in bf16 (--precision fp32 keeps fp32)")
    return "bf16", None


def available_cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def default_workers(requested: int) -> int:
    """Worker processes that do not oversubscribe the machine: at most one per core.

    On a CPU the data (simulation + features) costs more per trajectory than the model step, so
    the training process spends much of its time waiting for batches: one worker per core plus
    the training process (one thread each) keeps both busy without the paper preset's 4 workers
    fighting over 2 cores."""
    if requested <= 0:
        return 0
    return max(1, min(requested, available_cores()))


def _one_thread_worker(_: int) -> None:
    # Each worker simulates and extracts features on one core; two threads per process on a
    # 2-core machine made every process wait for the others' spinning OpenMP threads.
    torch.set_num_threads(1)


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
        self.saved = self._load_saved()
        recipe = options.recipe
        if self.saved is not None:  # the run keeps its recipe; only the epoch count may change
            recipe = Recipe.from_dict(self.saved["recipe"])
            if conflicts := resume_conflicts(recipe, options.recipe, options.recipe_options):
                raise ConfigError(f"{self.out} keeps the recipe it started with (only --epochs may change on "
                                  f"--resume), but {'; '.join(conflicts)}: drop the option or start a new run "
                                  "in another --out")
            if options.epochs is not None:
                recipe = recipe.replace(epochs=options.epochs)
        self.device = torch.device(options.device)
        if self.device.type == "cuda" and not torch.cuda.is_available():
            raise ConfigError("--device cuda requested but torch has no CUDA device here")
        saved_precision = None if self.saved is None else self.saved.get("precision")
        first_epoch = (self.saved or {}).get("history") or [{}]
        self.precision, note = resume_precision(saved_precision, options.precision, self.device,
                                                started_in=first_epoch[0].get("precision"))
        if note:
            log(note)
        torch.manual_seed(recipe.seed)  # network initialisation
        self.tracker = tracker if tracker is not None else make_tracker(options.tracker, **options.tracker_options)
        check_trainable(self.tracker, options.tracker)
        # What the run starts from: recorded in the checkpoint and in exported weights files.
        self.initial_weights: dict[str, Any] | None = None
        if self.saved is not None:
            self._check_task_version()
            self.initial_weights = self.saved.get("initial_weights")
        elif getattr(self.tracker, "trained", False):
            log(f"note: {options.tracker} loaded trained weights and training starts from them "
                "(pass --tracker-opt weights=random to train from scratch)")
            described = self.tracker.describe() if hasattr(self.tracker, "describe") else {}
            weights = described.get("weights")
            self.initial_weights = {"weights": None if weights is None else Path(weights).name,
                                    "sha256": described.get("weights_hash"), "training": described.get("training")}
        if recipe.t60 is None and "t60" in (defaults := training_defaults(self.tracker)):
            recipe = recipe.replace(t60=tuple(defaults["t60"]))
        self.recipe = recipe
        self.network: torch.nn.Module = self.tracker.network
        if self.saved is not None:
            self._check_same_network()
        self.network.to(self.device)
        self.channels_last = bool(options.compile) and any(isinstance(m, torch.nn.Conv3d)
                                                           for m in self.network.modules())
        if self.channels_last:  # oneDNN's fast (AMX) 3D convolutions want channels-last tensors
            self.network.to(memory_format=torch.channels_last_3d)
        self.train_forward = torch.compile(self.network) if options.compile else self.network
        self.frame_spec = self.tracker.frame_spec
        self.feature_fn = feature_fn or self._default_features()
        self.train_cache_dir = train_cache
        self.val_cache_dir = val_cache
        self.optimizer = torch.optim.Adam(self.network.parameters(), lr=recipe.phases[0].lr)
        requested = recipe.num_workers if options.workers is None else options.workers
        self.workers = default_workers(requested) if options.workers is None else max(0, int(options.workers))
        if options.threads:
            torch.set_num_threads(int(options.threads))
        elif self.device.type == "cpu" and self.workers > 0:
            torch.set_num_threads(1)  # one thread per process: the workers use the other cores
        self.base_seed = int(self.spec.base_seed) + int(recipe.seed)
        # Validation also scores the outputs under the tracker's hold rule (doabench.hold_in_silences;
        # None: the tracker never holds), the way `doabench run` will use the weights, and a new run
        # keeps the epoch that is best by that score. A run resumed from a state written before
        # that keeps its criterion (all frames, raw outputs), so its epochs stay comparable.
        self.hold_frames: int | None = getattr(self.tracker, "hold_frames", None)
        self.best_by = "val_rmsae_held" if self.saved is None else str(self.saved.get("best_by") or "val_rmsae_all")

    # -- setup ------------------------------------------------------------------------------
    def _load_saved(self) -> dict[str, Any] | None:
        path = self.out / ckpt.LATEST
        if not path.exists():
            return None
        if not self.options.resume:
            raise ConfigError(f"{self.out} already holds a training run; pass --resume to continue it "
                              "or choose another --out")
        self._saved_stamp = _stamp(path)
        return ckpt.load_checkpoint(path)

    def _check_task_version(self) -> None:
        """A run continues on the task (and task version) it started with: a changed training
        distribution would silently mix two datasets in one run."""
        task = self.saved.get("task")
        if task is not None and task != self.spec.id:
            raise ConfigError(f"{self.out} was trained on task {task}, not {self.spec.id}; resume it with --task "
                              f"{task} or start a new run in another --out")
        version = self.saved.get("task_version")
        config = self.out / "config.json"
        if version is None and config.exists():  # states written before checkpoints recorded it
            version = json.loads(config.read_text()).get("task_version")
        if version is not None and int(version) != int(self.spec.version):
            raise ConfigError(f"{self.out} was trained on {self.spec.id} version {version} and the task is now "
                              f"version {self.spec.version}; start a new run (another --out) or continue it with "
                              f"the version {version} task file")

    def _check_same_network(self) -> None:
        """The resumed run's weights must fit the asked tracker's network (a different model or
        resolution would otherwise fail deep in ``load_state_dict``)."""
        want = {k: tuple(v.shape) for k, v in self.network.state_dict().items()}
        have = {k: tuple(v.shape) for k, v in self.saved["model"].items()}
        if want != have:
            raise ConfigError(f"{self.out} holds a run of {self.saved.get('tracker', 'another tracker')} whose "
                              f"weights do not fit {self.options.tracker}; resume it with that --tracker or "
                              "start a new run in another --out")

    def _default_features(self) -> FeatureFn:
        """Batched features ``(B, M, L)`` audio -> ``{kind: (B, T, ...)}`` tensors on the training
        device: the extractor of the tracker's :class:`~doabench.features.plan.ObservationPlan`
        (the one the environment and make-dataset use), asked for the tracker's kinds as they are
        so that a kind it cannot compute gets the extractor's own error."""
        from doabench.arrays import get_array
        from doabench.features.kinds import DEFAULT_RESOLUTION
        from doabench.features.plan import ObservationPlan

        declared = feature_options(self.tracker)
        plan = ObservationPlan(self.tracker.features, get_array(self.spec.array), self.frame_spec,
                               (self.tracker.resolution or DEFAULT_RESOLUTION,), declared["delays"],
                               declared["spectrogram_frame_spec"])
        extractor = plan.extractor(kinds=tuple(self.tracker.features))
        return lambda audio, vad: extractor(audio, vad)

    def _val_cache(self) -> TrajectoryCache:
        if self.val_cache_dir is None:
            folder = cache_folder(self.options.cache_root, self.spec, self.recipe, "val")
            if len(_available(folder)) < self.recipe.val_trajectories:
                self.log(f"building the validation cache {folder} ({self.recipe.val_trajectories} trajectories)")
                ensure_cache(self.options.cache_root, self.spec, self.recipe, "val", self.recipe.val_trajectories,
                             self.options.librispeech, self.options.simulator, self.log)
            self.val_cache_dir = folder
        return TrajectoryCache(self.val_cache_dir)

    def _train_cache(self) -> TrajectoryCache:
        if self.train_cache_dir is None:
            self.train_cache_dir = cache_folder(self.options.cache_root, self.spec, self.recipe, "train")
        need = min(self.options.min_cache, self.recipe.cache_size)
        while len(_contiguous(_available(self.train_cache_dir))) < need:
            if not (self.train_cache_dir / "manifest.json").exists():
                raise NotFoundError(f"no training cache at {self.train_cache_dir}; build it first with "
                                    "`doabench train ... --build-cache`")
            self.log(f"waiting for {need} cached trajectories in {self.train_cache_dir}")
            time.sleep(30)
        return TrajectoryCache(self.train_cache_dir)

    def _epoch_items(self, epoch: int, snr: tuple[float, float]):
        r = self.recipe
        if self.options.dataset is not None:
            return DatasetItems(self.options.dataset, tuple(self.tracker.features), self.tracker.resolution,
                                self.base_seed, epoch, r.trajectories_per_epoch), 0
        if r.data == "cache":
            cache = self._train_cache()
            n_cache = min(len(_contiguous(cache.available())), r.cache_size)
            return CachedItems(cache, n_cache, self.base_seed, epoch, r.trajectories_per_epoch, snr,
                               self.frame_spec), n_cache
        from doabench.acoustics.simulators import get_simulator
        from doabench.arrays import get_array

        if not hasattr(self, "_sim_parts"):
            self._sim_parts = (speech_for_split(self.spec, "train", self.options.librispeech, r.val_speaker_fraction),
                               get_array(self.spec.array), get_simulator(self.options.simulator,
                                                                         device=self._data_device()))
        speech, array, sim = self._sim_parts
        dist = scene_distribution(self.spec, r).replace(snr=tuple(snr))
        items = SimulatedItems(dist, speech, array, sim, self.base_seed, epoch, r.trajectories_per_epoch,
                               self.frame_spec)
        # Features (and the network input) are computed next to the simulation, in the workers.
        return NetworkInputs(items, self.item_input), 0

    # -- one step, validation ------------------------------------------------------------------
    def network_input(self, batch: Mapping[str, torch.Tensor]) -> torch.Tensor:
        with torch.no_grad():
            if "input" in batch:  # computed by the data workers
                return batch["input"]
            if "features" in batch:  # stored features (dataset file)
                return self.tracker.network_input(dict(batch["features"]))
            feats = dict(self.feature_fn(batch["audio"], batch["sample_vad"]))
            return self.tracker.network_input(feats)

    def _data_device(self) -> torch.device:
        """Where simulation and features run: the training device when the training process does
        the data work itself (no workers; e.g. everything on one GPU), else the workers' CPU."""
        return self.device if self.workers == 0 else torch.device("cpu")

    def item_input(self, audio: torch.Tensor, sample_vad: torch.Tensor) -> torch.Tensor:
        """The network input of one item (``audio`` ``(M, L)``, ``sample_vad`` ``(L,)``), without its batch axis."""
        dev = self._data_device()
        with torch.no_grad():
            feats = self.feature_fn(audio[None].to(dev), sample_vad[None].to(dev))
            return self.tracker.network_input(dict(feats))[0]

    def _autocast(self):
        if self.precision != "bf16":
            return contextlib.nullcontext()
        return torch.autocast(self.device.type, dtype=torch.bfloat16)

    def _to_device(self, x: torch.Tensor) -> torch.Tensor:
        x = x.to(self.device, non_blocking=True)
        if self.channels_last and x.dim() == 5:
            x = x.contiguous(memory_format=torch.channels_last_3d)
        return x

    def forward(self, x: torch.Tensor, truth: torch.Tensor, network: Callable | None = None) -> torch.Tensor:
        with self._autocast():  # bf16 activations, float32 master weights and loss
            y = (self.network if network is None else network)(x).float()
        if y.shape != truth.shape:
            raise ConfigError(f"tracker {self.options.tracker!r}: network output {tuple(y.shape)} does not match "
                              f"the truth {tuple(truth.shape)} (B, T, 3)")
        return y

    def train_step(self, batch: Mapping[str, torch.Tensor]) -> float:
        """One Adam step on ``batch``; returns the loss before the step."""
        self.network.train()
        x = self._to_device(self.network_input(batch))
        truth = batch["truth"].to(self.device)
        loss = torch.nn.functional.mse_loss(self.forward(x, truth, self.train_forward), truth)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        return float(loss.detach())

    def prepare_validation(self) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
        """Network inputs, truth and frame VAD of the fixed validation set (computed once)."""
        items = ValidationItems(self._val_cache(), self.recipe.val_trajectories, self.base_seed, self.frame_spec)
        loader = DataLoader(items, batch_size=4, shuffle=False, num_workers=0, collate_fn=collate)
        return [(self.network_input(b), b["truth"], b["vad"]) for b in loader]

    @torch.no_grad()
    def validate(self, val: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]) -> dict[str, float]:
        from doabench.arrays import get_array
        from doabench.metrics import score_frames

        self.network.eval()
        losses, outputs, held, truths, active = [], [], [], [], []
        for x, truth, vad in val:
            x, truth = self._to_device(x), truth.to(self.device)
            y = self.forward(x, truth).cpu()  # (B, T, 3)
            truth = truth.cpu()
            losses.append(torch.nn.functional.mse_loss(y, truth, reduction="none").mean(-1).flatten())
            outputs.append(y.reshape(-1, 3))
            if self.hold_frames is not None:
                index = torch.from_numpy(held_frame_index(vad.numpy(), self.hold_frames))  # (B, T)
                held.append(torch.gather(y, 1, index[..., None].expand_as(y)).reshape(-1, 3))
            truths.append(truth.reshape(-1, 3))
            active.append(vad.flatten())
        # Scored as `doabench run` scores an episode (doabench.metrics.score_frames: planar folding,
        # silent frames in the all-frames RMSAE only), so the log's numbers mean what the results' do.
        t, a = torch.cat(truths).double().numpy(), torch.cat(active).numpy().astype(bool)
        planar = get_array(self.spec.array).planar

        def scored(y: list[torch.Tensor]) -> dict[str, float]:
            return score_frames(torch.cat(y).double().numpy(), t, a, planar=planar).summary()

        raw = scored(outputs)
        return {"val_loss": float(torch.cat(losses).mean()), "val_rmsae_all": raw["rmsae_all"],
                "val_rmsae_nonsilent": raw["rmsae_nonsilent"],
                "val_rmsae_held": scored(held)["rmsae_all"] if held else raw["rmsae_all"]}

    # -- the loop ---------------------------------------------------------------------------------
    def run(self) -> list[dict[str, Any]]:
        """Train; returns the epoch history. One process at a time writes a run folder: a second
        ``train --out`` of the same folder gets one line naming the first one's pid."""
        if self.options.dataset is None and self.recipe.data == "cache":
            self._train_cache()  # a missing cache is an error before the run folder is written
        if not self.is_writer:
            return self._run()
        with exclusive_lock(self.out / LOCK_NAME, f"the training run {self.out}"):
            if _stamp(self.out / ckpt.LATEST) != getattr(self, "_saved_stamp", None):
                raise InputError(f"another process wrote {self.out / ckpt.LATEST} while this one started; "
                                 "run the command again to continue from it")
            return self._run()

    def _run(self) -> list[dict[str, Any]]:
        if self.options.dataset is None and self.recipe.data == "cache":
            self._train_cache()  # a missing cache is an error before the run folder is written
        self.out.mkdir(parents=True, exist_ok=True)
        history: list[dict[str, Any]] = []
        start, best, compute_s, seen = 0, math.inf, 0.0, 0
        best_epoch, best_weights = 0, None
        if self.saved is not None:
            s = self.saved
            self.network.load_state_dict(s["model"])
            best_epoch = int(s.get("best_epoch") or s["epoch"])
            if s.get("best_model") is not None:
                best_weights = s["best_model"]
            self.optimizer.load_state_dict(s["optimizer"])
            ckpt.set_rng_state(s["rng"])
            start, history, best = int(s["epoch"]), list(s["history"]), float(s["best"])
            # Rows of runs that predate the per-epoch record trained in the run's saved precision.
            history = [{"precision": s.get("precision"), **row} for row in history]
            compute_s, seen = float(s["compute_s"]), int(s["trajectories_seen"])
            self.log(f"resuming {self.out} after epoch {start}")
        if self.is_writer:  # data-parallel hook
            write_json(self.out / "config.json", self.describe())
        val = self.prepare_validation()
        if self.initial_weights is not None and "validation" not in self.initial_weights:
            # the starting point on this run's validation set, to compare the epochs with
            self.initial_weights["validation"] = start_metrics = self.validate(val)
            self.log(f"starting weights: val loss {start_metrics['val_loss']:.4f}, val RMSAE "
                     f"{start_metrics['val_rmsae_all']:.2f} deg (non-silent {start_metrics['val_rmsae_nonsilent']:.2f})")
        ran = 0
        self.stop_state = {"kept": start, "epoch": None}
        for epoch in range(start, self.recipe.epochs):
            if self.options.max_epochs is not None and ran >= self.options.max_epochs:
                break
            t0 = time.perf_counter()
            # The weights going into this epoch are the best so far when best_weights is None.
            previous_weights = copy.deepcopy(self.network.state_dict()) if best_weights is None else None
            phase = self.recipe.phase(epoch)
            for group in self.optimizer.param_groups:
                group["lr"] = phase.lr
            items, n_cache = self._epoch_items(epoch, phase.snr)
            # Workers run ahead (prefetch) so the model step never waits for the simulator.
            loader = DataLoader(items, batch_size=phase.batch_size, shuffle=False, collate_fn=collate,
                                num_workers=self.workers, worker_init_fn=_one_thread_worker if self.workers else None,
                                prefetch_factor=4 if self.workers else None, persistent_workers=False)
            if self.dist is not None:  # data-parallel hook: this rank's share of each global batch
                loader = self.dist.loader(self, items, phase.batch_size)
            losses = []
            self.stop_state.update(epoch=epoch + 1, since=t0, batches=0, of=_batches(loader))
            with EpochProgress(loader_length(loader), f"epoch {epoch + 1}/{self.recipe.epochs}",
                               self.options.progress) as bar:
                for batch in loader:
                    losses.append(self.train_step(batch))
                    self.stop_state["batches"] += 1
                    bar.step(float(np.mean(losses[-20:])))
            metrics = self.validate(val)
            epoch_s = time.perf_counter() - t0
            compute_s += epoch_s
            seen += len(items)
            row = {"epoch": epoch + 1, "phase_snr": f"{phase.snr[0]:g}-{phase.snr[1]:g}", "precision": self.precision,
                   "batch_size": phase.batch_size, "lr": phase.lr, "train_loss": float(np.mean(losses)),
                   **metrics, "n_cache": n_cache, "trajectories_seen": seen, "epoch_s": round(epoch_s, 1),
                   "compute_s": round(compute_s, 1), "trajectories_per_s": round(len(items) / epoch_s, 3)}
            history.append(row)
            score = metrics[self.best_by]
            if score < best:  # the latest weights are the best: stored once, as "model"
                best, best_epoch, best_weights = score, epoch + 1, None
            elif best_weights is None:  # keep the previous best before the latest moves on
                best_weights = previous_weights
            state = {"epoch": epoch + 1, "model": self.network.state_dict(), "best_model": best_weights,
                     "best_epoch": best_epoch, "optimizer": self.optimizer.state_dict(),
                     "rng": ckpt.rng_state(), "recipe": self.recipe.to_dict(), "tracker": self.options.tracker,
                     "task": self.spec.id, "task_version": self.spec.version,
                     "initial_weights": self.initial_weights, "history": history, "compute_s": compute_s, "trajectories_seen": seen,
                     "threads": torch.get_num_threads(), "precision": self.precision,
                     "device": str(self.device), "workers": self.workers, "compiled": bool(self.options.compile),
                     "best": best, "best_by": self.best_by}
            if self.is_writer:  # data-parallel hook: rank 0 alone writes the run folder
                ckpt.save_checkpoint(self.out / ckpt.LATEST, state)
                write_log(self.out / "log.csv", history)
                plot_history(self.out / "loss.png", history, self.options.tracker)
            self.stop_state.update(kept=epoch + 1, epoch=None)
            self.log(f"epoch {epoch + 1}: train loss {row['train_loss']:.4f}, val loss {metrics['val_loss']:.4f}, "
                     f"val RMSAE {metrics['val_rmsae_all']:.2f} deg (non-silent {metrics['val_rmsae_nonsilent']:.2f}, "
                     f"held {metrics['val_rmsae_held']:.2f}), {epoch_s:.0f} s")
            ran += 1
        return history

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
        return {"tracker": self.options.tracker, "task": self.spec.id, "task_version": self.spec.version,
                "recipe": self.recipe.to_dict(), "frame": self.frame_spec.to_dict(),
                "features": list(self.tracker.features),
                "resolution": None if self.tracker.resolution is None else list(self.tracker.resolution),
                "dataset": None if self.options.dataset is None else str(self.options.dataset),
                "train_cache": None if self.train_cache_dir is None else str(self.train_cache_dir),
                "initial_weights": None if self.initial_weights is None else {
                    k: self.initial_weights.get(k) for k in ("weights", "sha256")},
                "threads": torch.get_num_threads(), "torch": torch.__version__, "precision": self.precision,
                "compile": bool(self.options.compile), "workers": self.workers, "device": str(self.device),
                "hold_frames": self.hold_frames, "best_by": self.best_by}


def _stamp(path: Path) -> tuple[int, int, int] | None:
    """A checkpoint's identity on disk (inode, size, mtime): changed by any rewrite."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_ino, st.st_size, st.st_mtime_ns


def _batches(loader) -> int | None:
    try:
        return len(loader)
    except TypeError:
        return None


def _available(folder: Path) -> list[int]:
    return sorted(int(p.stem) for p in Path(folder).glob("[0-9]*.npz")) if Path(folder).is_dir() else []


def _contiguous(indices: list[int]) -> list[int]:
    """The leading run ``0, 1, 2, ...`` of sorted indices (items are used in order)."""
    n = 0
    for i in indices:
        if i != n:
            break
        n += 1
    return list(range(n))


def write_log(path: Path, history: list[dict[str, Any]]) -> None:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=CSV_COLUMNS, extrasaction="ignore")
    writer.writeheader()
    writer.writerows(history)
    write_text(path, buf.getvalue())


def plot_history(path: Path, history: list[dict[str, Any]], title: str) -> None:
    """Loss curves (train, validation) and validation RMSAE per epoch, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    epochs = [h["epoch"] for h in history]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    ax1.plot(epochs, [h["train_loss"] for h in history], label="train")
    ax1.plot(epochs, [h["val_loss"] for h in history], label="validation")
    ax1.set_xlabel("epoch")
    ax1.set_ylabel("MSE loss")
    ax1.set_yscale("log")
    ax1.legend()
    ax2.plot(epochs, [h["val_rmsae_all"] for h in history], label="all frames")
    ax2.plot(epochs, [h["val_rmsae_nonsilent"] for h in history], label="non-silent frames")
    held = [(h["epoch"], h["val_rmsae_held"]) for h in history if h.get("val_rmsae_held") is not None]
    if held:  # epochs validated since the hold rule was scored
        ax2.plot(*zip(*held), label="all frames, held in silences")
    ax2.set_xlabel("epoch")
    ax2.set_ylabel("validation RMSAE (deg)")
    ax2.legend()
    fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)
