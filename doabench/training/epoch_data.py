"""Where the trainer's items come from, epoch by epoch, and the processes that make them.

:class:`EpochData` picks the source the run asks for (a ``make-dataset`` file, the trajectory
cache of the ``cpu`` preset, or simulation on the fly), waits for or builds the caches of
:mod:`.pipeline`, and wraps an epoch's items in the DataLoader that feeds the training process.
The items themselves are the seeded datasets of :mod:`.data`.
"""
from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any, Callable, Mapping

import torch
from torch.utils.data import DataLoader, Dataset

from doabench.envs.spec import TaskSpec
from doabench.errors import NotFoundError
from doabench.framing import FrameSpec
from doabench.training.cache import TrajectoryCache
from doabench.training.data import CachedItems, DatasetItems, NetworkInputs, SimulatedItems, ValidationItems, collate
from doabench.training.pipeline import (cache_folder, check_memory, ensure_cache, scene_distribution, simulation_note,
                                        speech_for_split)
from doabench.training.protocol import training_observations
from doabench.training.recipes import Recipe

FeatureFn = Callable[[torch.Tensor, torch.Tensor], Mapping[str, torch.Tensor]]
#: ``(audio (M, L), sample_vad (L,)) -> network input (C, T, ...)`` of one item
ItemInputFn = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
# Items of the fixed validation set per batch (the network input of every batch is kept in memory).
VALIDATION_BATCH = 4


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


def one_thread_worker(_: int) -> None:
    """DataLoader ``worker_init_fn``: each worker simulates and extracts features on one core."""
    # Two threads per process on a 2-core machine made every process wait for the others'
    # spinning OpenMP threads.
    torch.set_num_threads(1)


def loader_options(workers: int) -> dict[str, Any]:
    """The DataLoader settings of training batches with ``workers`` processes: each worker runs
    ahead (prefetch) so the model step never waits for the simulator."""
    return {"collate_fn": collate, "num_workers": workers, "worker_init_fn": one_thread_worker if workers else None,
            "prefetch_factor": 4 if workers else None, "persistent_workers": False}


def cached_indices(folder: Path) -> list[int]:
    """The item indices a cache folder holds, sorted."""
    return sorted(int(p.stem) for p in Path(folder).glob("[0-9]*.npz")) if Path(folder).is_dir() else []


def leading_run(indices: list[int]) -> list[int]:
    """The leading run ``0, 1, 2, ...`` of sorted indices (items are used in order)."""
    n = 0
    for i in indices:
        if i != n:
            break
        n += 1
    return list(range(n))


def default_features(tracker: Any, spec: TaskSpec) -> FeatureFn:
    """Batched features ``(B, M, L)`` audio -> ``{kind: (B, T, ...)}`` tensors on the audio's
    device: the extractor of the tracker's :class:`~doabench.features.plan.ObservationPlan` (the
    one the environment and make-dataset use), asked for the tracker's kinds as they are so that
    a kind it cannot compute gets the extractor's own error."""
    from doabench.arrays import get_array

    plan = training_observations(tracker).plan(get_array(spec.array))
    extractor = plan.extractor(kinds=tuple(tracker.features))
    return lambda audio, vad: extractor(audio, vad)


class EpochData:
    """The training and validation items of a run (see the module docstring).

    ``options`` is the run's :class:`~doabench.training.trainer.TrainOptions` (data source, cache
    root, speech corpus, simulator, ``min_cache``); ``item_input`` turns a simulated item into its
    network input inside the workers; ``workers`` DataLoader processes make the items (0: the
    training process itself, on ``device``). ``train_cache`` and ``val_cache`` may name cache
    folders (tests, tools); by default they are the recipe's folders under the cache root.
    """

    def __init__(self, options: Any, spec: TaskSpec, recipe: Recipe, frame_spec: FrameSpec, tracker: Any,
                 item_input: ItemInputFn, workers: int, device: torch.device,
                 train_cache: Path | None = None, val_cache: Path | None = None,
                 log: Callable[[str], None] = print) -> None:
        self.options, self.spec, self.recipe, self.frame_spec = options, spec, recipe, frame_spec
        self.tracker, self.item_input, self.workers, self.device, self.log = tracker, item_input, workers, device, log
        self.train_cache_dir, self.val_cache_dir = train_cache, val_cache
        self.base_seed = int(spec.base_seed) + int(recipe.seed)
        self._simulation: tuple[Any, Any, Any] | None = None
        if options.dataset is None:  # the scenes are simulated: refused here if they cannot fit
            check_memory(spec, recipe, options.simulator)
            if recipe.data == "simulate" and (note := simulation_note(
                    spec, recipe, options.simulator, recipe.trajectories_per_epoch, max(1, workers), "an epoch")):
                log(note)  # a slow engine says so before the first epoch

    def data_device(self) -> torch.device:
        """Where simulation and features run: the training device when the training process does
        the data work itself (no workers; e.g. everything on one GPU), else the workers' CPU."""
        return self.device if self.workers == 0 else torch.device("cpu")

    def val_cache(self) -> TrajectoryCache:
        """The validation cache, its missing items simulated first."""
        if self.val_cache_dir is None:
            folder = cache_folder(self.options.cache_root, self.spec, self.recipe, "val")
            if len(cached_indices(folder)) < self.recipe.val_trajectories:  # it says where and how big first
                ensure_cache(self.options.cache_root, self.spec, self.recipe, "val", self.recipe.val_trajectories,
                             self.options.librispeech, self.options.simulator, self.log)
            self.val_cache_dir = folder
        return TrajectoryCache(self.val_cache_dir)

    def train_cache(self) -> TrajectoryCache:
        """The training cache of the ``cpu`` preset, once it holds ``min_cache`` leading items
        (another process may still be building it: wait); an error when there is none."""
        if self.train_cache_dir is None:
            self.train_cache_dir = cache_folder(self.options.cache_root, self.spec, self.recipe, "train")
        need = min(self.options.min_cache, self.recipe.cache_size)
        while len(leading_run(cached_indices(self.train_cache_dir))) < need:
            if not (self.train_cache_dir / "manifest.json").exists():
                raise NotFoundError(f"no training cache at {self.train_cache_dir}; build it first with "
                                    "`doabench train ... --build-cache`")
            self.log(f"waiting for {need} cached trajectories in {self.train_cache_dir}")
            time.sleep(30)
        return TrajectoryCache(self.train_cache_dir)

    def epoch_items(self, epoch: int, snr: tuple[float, float]) -> tuple[DatasetItems | CachedItems | NetworkInputs, int]:
        """Epoch ``epoch``'s items at the phase's ``snr`` range, and how many cached trajectories
        they draw from (0 when not from a cache)."""
        r = self.recipe
        if self.options.dataset is not None:
            return DatasetItems(self.options.dataset, tuple(self.tracker.features), self.tracker.resolution,
                                self.base_seed, epoch, r.trajectories_per_epoch), 0
        if r.data == "cache":
            cache = self.train_cache()
            n_cache = min(len(leading_run(cache.available())), r.cache_size)
            return CachedItems(cache, n_cache, self.base_seed, epoch, r.trajectories_per_epoch, snr,
                               self.frame_spec), n_cache
        speech, array, simulator = self._simulation_parts()
        dist = scene_distribution(self.spec, r).replace(snr=tuple(snr))
        items = SimulatedItems(dist, speech, array, simulator, self.base_seed, epoch, r.trajectories_per_epoch,
                               self.frame_spec)
        # Features (and the network input) are computed next to the simulation, in the workers.
        return NetworkInputs(items, self.item_input), 0

    def _simulation_parts(self) -> tuple[Any, Any, Any]:
        """Training speech, array and simulator, made once per run (the speech index is costly)."""
        if self._simulation is None:
            from doabench.acoustics.simulators import get_simulator
            from doabench.arrays import get_array

            self._simulation = (
                speech_for_split(self.spec, "train", self.options.librispeech, self.recipe.val_speaker_fraction),
                get_array(self.spec.array), get_simulator(self.options.simulator, device=self.data_device()))
        return self._simulation

    def loader(self, items: Dataset, batch_size: int) -> DataLoader:
        """The epoch's batches, in item order."""
        return DataLoader(items, batch_size=batch_size, shuffle=False, **loader_options(self.workers))

    def validation_loader(self) -> DataLoader:
        """The fixed validation set's batches (made in the training process)."""
        items = ValidationItems(self.val_cache(), self.recipe.val_trajectories, self.base_seed, self.frame_spec)
        return DataLoader(items, batch_size=VALIDATION_BATCH, shuffle=False, num_workers=0, collate_fn=collate)
