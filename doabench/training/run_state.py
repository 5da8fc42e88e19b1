"""A run folder's state as the trainer resumes and saves it.

:mod:`.checkpoint` reads and writes the file; this module decides what a saved state means for
the run that continues it: whether it may continue (``--resume`` given, same task and task
version, a network its weights fit, the recipe it started with), where the loop picks up
(:class:`RunProgress`), and what the trainer writes after each epoch (:func:`checkpoint_state`).

States written by older versions of the trainer lack some fields; their meaning is filled in here
and nowhere else:

* ``task_version``: read from the run's ``config.json``;
* ``best_epoch``: the state's own epoch;
* ``best_by``: ``val_rmsae_all`` (validation did not yet score the hold rule, so the run keeps
  selecting by all frames and raw outputs, and its epochs stay comparable);
* the per-epoch ``precision`` of history rows: the run's saved precision.
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import torch

from doabench.envs.spec import TaskSpec
from doabench.errors import ConfigError
from doabench.features.spec import ObservationSpec
from doabench.training import checkpoint as ckpt
from doabench.training.recipes import Recipe, resume_conflicts, resumed_phases

#: what a new run selects its best epoch by (the score under the tracker's hold rule)
BEST_BY = "val_rmsae_held"
#: what a state without ``best_by`` selected by
LEGACY_BEST_BY = "val_rmsae_all"

Stamp = tuple[int, int, int]


def checkpoint_stamp(path: Path) -> Stamp | None:
    """A checkpoint's identity on disk (inode, size, mtime): changed by any rewrite."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_ino, st.st_size, st.st_mtime_ns


def load_saved_run(out: Path, resume: bool) -> tuple[dict[str, Any] | None, Stamp | None]:
    """The state of the run in ``out`` (None for a new run) and its stamp, to tell later whether
    another process rewrote it. A run folder with a checkpoint needs ``resume``."""
    path = out / ckpt.LATEST
    if not path.exists():
        return None, None
    if not resume:
        raise ConfigError(f"{out} already holds a training run; pass --resume to continue it "
                          "or choose another --out")
    stamp = checkpoint_stamp(path)
    return ckpt.load_checkpoint(path), stamp


def resumed_recipe(saved: Mapping[str, Any], requested: Recipe, given: tuple[str, ...], epochs: int | None,
                   out: Path) -> Recipe:
    """The recipe a resumed run continues with: its own, with a new epoch count when ``epochs``
    is given and a phase switch moved when ``--switch-epoch`` is given and neither the old nor the
    new switch lies in the epochs already trained. Any other recipe option in ``given`` that
    differs from the run's is an error."""
    recipe = Recipe.from_dict(saved["recipe"])
    epochs_done = int(saved.get("epoch") or 0)
    if conflicts := resume_conflicts(recipe, requested, given, epochs_done):
        raise ConfigError(f"{out} keeps the recipe it started with (only --epochs, and --switch-epoch "
                          f"from epoch {epochs_done} on, may change on --resume), but {'; '.join(conflicts)}: "
                          "drop the option or start a new run in another --out")
    recipe = resumed_phases(recipe, requested, given, epochs_done)
    return recipe if epochs is None else recipe.replace(epochs=epochs)


def saved_precisions(saved: Mapping[str, Any] | None) -> tuple[str | None, str | None]:
    """The precision of the run's latest epochs and of its first epoch (None when unrecorded)."""
    if saved is None:
        return None, None
    first_epoch = saved.get("history") or [{}]
    return saved.get("precision"), first_epoch[0].get("precision")


def check_same_task(saved: Mapping[str, Any], spec: TaskSpec, out: Path) -> None:
    """A run continues on the task (and task version) it started with: a changed training
    distribution would silently mix two datasets in one run."""
    task = saved.get("task")
    if task is not None and task != spec.id:
        raise ConfigError(f"{out} was trained on task {task}, not {spec.id}; resume it with --task "
                          f"{task} or start a new run in another --out")
    version = saved.get("task_version")
    config = out / "config.json"
    if version is None and config.exists():
        version = json.loads(config.read_text()).get("task_version")
    if version is not None and int(version) != int(spec.version):
        raise ConfigError(f"{out} was trained on {spec.id} version {version} and the task is now "
                          f"version {spec.version}; start a new run (another --out) or continue it with "
                          f"the version {version} task file")


def check_same_network(saved: Mapping[str, Any], network: torch.nn.Module, tracker: str, out: Path) -> None:
    """The resumed run's weights must fit the asked tracker's network (a different model or
    resolution would otherwise fail deep in ``load_state_dict``)."""
    want = {k: tuple(v.shape) for k, v in network.state_dict().items()}
    have = {k: tuple(v.shape) for k, v in saved["model"].items()}
    if want != have:
        raise ConfigError(f"{out} holds a run of {saved.get('tracker', 'another tracker')} whose "
                          f"weights do not fit {tracker}; resume it with that --tracker or "
                          "start a new run in another --out")


def build_options(tracker_options: Mapping[str, Any]) -> dict[str, Any]:
    """The tracker options that build the run's network as it trains, recorded in the checkpoint
    so that an export builds the same tracker: all but ``weights`` (an export loads the run's own)."""
    return {k: v for k, v in tracker_options.items() if k != "weights"}


def check_same_observations(saved: Mapping[str, Any], observations: Any, out: Path) -> None:
    """A resumed run must read what it started on (a tracker option such as a spectrogram tracker's
    ``phase`` changes the observations, not the network's shapes); runs older than the record pass."""
    recorded = saved.get("observations")
    if recorded is not None and recorded != observations.to_dict():
        raise ConfigError(f"{out} holds a run trained on {ObservationSpec.from_dict(recorded)}, not on "
                          f"{observations}; resume it with the tracker options it started with "
                          f"({_options_text(saved.get('tracker_options'))}) or start a new run in another --out")


def _options_text(options: Mapping[str, Any] | None) -> str:
    return ", ".join(f"--tracker-opt {k}={v}" for k, v in (options or {}).items()) or "none besides weights"


def initial_weights(saved: Mapping[str, Any] | None, tracker: Any, name: str,
                    log: Callable[[str], None]) -> dict[str, Any] | None:
    """What the run starts from, recorded in the checkpoint and in exported weights files: None
    for random weights, else the trained weights file the tracker loaded (a resumed run keeps
    its record, with the starting point's validation scores once they are known)."""
    if saved is not None:
        return saved.get("initial_weights")
    if not getattr(tracker, "trained", False):
        return None
    log(f"note: {name} loaded trained weights and training starts from them "
        "(pass --tracker-opt weights=random to train from scratch)")
    described = tracker.describe() if hasattr(tracker, "describe") else {}
    weights = described.get("weights")
    return {"weights": None if weights is None else Path(weights).name,
            "sha256": described.get("weights_hash"), "training": described.get("training")}


def warm_start(saved: Mapping[str, Any] | None, tracker: Any, source_id: str, source_options: Mapping[str, Any],
               out: Path, log: Callable[[str], None]) -> dict[str, Any]:
    """Start a new run's network from the trained tracker ``source_id`` (``--warm-start``) and return
    the record of it; a resumed run keeps its own starting point, which must be that one. Refused
    in one line before training: a tracker without the protocol's ``warm_start_from``, or weights
    of another model, feature set, frame grid or array (the tracker's own checks)."""
    from doabench.trackers.registry import make_tracker

    source = make_tracker(source_id, **dict(source_options))
    digest = source.weights_hash()
    if saved is not None:
        recorded = saved.get("initial_weights") or {}
        if recorded.get("sha256") != digest:
            raise ConfigError(f"{out} started from {recorded.get('weights') or 'random weights'}, not from the "
                              f"weights of --warm-start {source_id}; resume it without --warm-start")
        return dict(recorded)
    if not callable(getattr(tracker, "warm_start_from", None)):
        raise ConfigError(f"--warm-start: the trained tracker has no warm_start_from(source) to take weights "
                          f"from {source_id}")
    tracker.warm_start_from(source)
    described = source.describe() if hasattr(source, "describe") else {}
    weights = described.get("weights")
    log(f"warm start: the network starts from {source_id}'s weights"
        f"{'' if weights is None else ' (' + Path(weights).name + ')'}")
    return {"weights": None if weights is None else Path(weights).name, "sha256": digest,
            "training": described.get("training"), "warm_start": {"tracker": source_id,
                                                                  "resolution": list(source.resolution or []) or None}}


def best_by(saved: Mapping[str, Any] | None) -> str:
    """The validation score a run selects its best epoch by (see the module docstring)."""
    return BEST_BY if saved is None else str(saved.get("best_by") or LEGACY_BEST_BY)


@dataclass
class RunProgress:
    """What the loop carries from epoch to epoch and saves after each: ``epoch`` epochs done, their
    ``history`` rows, the ``best`` score, its epoch and weights (``best_weights`` None: the latest
    weights are the best, stored once), and the run's compute seconds and trajectories."""

    epoch: int = 0
    history: list[dict[str, Any]] = field(default_factory=list)
    best: float = math.inf
    best_epoch: int = 0
    best_weights: dict[str, torch.Tensor] | None = None
    compute_s: float = 0.0
    trajectories_seen: int = 0

    @classmethod
    def from_saved(cls, saved: Mapping[str, Any]) -> "RunProgress":
        # Rows of runs that predate the per-epoch record trained in the run's saved precision.
        history = [{"precision": saved.get("precision"), **row} for row in saved["history"]]
        return cls(epoch=int(saved["epoch"]), history=history, best=float(saved["best"]),
                   best_epoch=int(saved.get("best_epoch") or saved["epoch"]), best_weights=saved.get("best_model"),
                   compute_s=float(saved["compute_s"]), trajectories_seen=int(saved["trajectories_seen"]))

    @property
    def latest_is_best(self) -> bool:
        """Whether the weights going into the next epoch are the best so far (and, once the epoch
        has moved them on, would be lost unless kept)."""
        return self.best_weights is None

    def add_epoch(self, row: dict[str, Any], score: float, weights_before: dict[str, torch.Tensor] | None) -> None:
        """Record the finished epoch ``row`` with its selection ``score``; ``weights_before``:
        the weights the epoch started from, when :attr:`latest_is_best` was true."""
        self.history.append(row)
        self.epoch = int(row["epoch"])
        if score < self.best:
            self.best, self.best_epoch, self.best_weights = score, self.epoch, None
        elif self.best_weights is None:
            self.best_weights = weights_before


def restore(saved: Mapping[str, Any], network: torch.nn.Module, optimizer: torch.optim.Optimizer) -> None:
    """Load the saved weights, Adam state and RNG states (in that order)."""
    network.load_state_dict(saved["model"])
    optimizer.load_state_dict(saved["optimizer"])
    ckpt.set_rng_state(saved["rng"])


def checkpoint_state(progress: RunProgress, network: torch.nn.Module, optimizer: torch.optim.Optimizer,
                     run: Mapping[str, Any], setup: Mapping[str, Any], best_by: str) -> dict[str, Any]:
    """The state :func:`.checkpoint.save_checkpoint` writes after an epoch. ``run``: ``recipe``,
    ``tracker``, ``task``, ``task_version``, ``initial_weights``; ``setup``: how this invocation
    trained (``threads``, ``precision``, ``device``, ``workers``, ``compiled``)."""
    return {"epoch": progress.epoch, "model": network.state_dict(), "best_model": progress.best_weights,
            "best_epoch": progress.best_epoch, "optimizer": optimizer.state_dict(), "rng": ckpt.rng_state(),
            "recipe": run["recipe"], "tracker": run["tracker"], "task": run["task"],
            "task_version": run["task_version"], "initial_weights": run["initial_weights"],
            "tracker_options": run.get("tracker_options") or {}, "observations": run.get("observations"),
            "history": progress.history, "compute_s": progress.compute_s,
            "trajectories_seen": progress.trajectories_seen, "threads": setup["threads"],
            "precision": setup["precision"], "device": setup["device"], "workers": setup["workers"],
            "compiled": setup["compiled"], "best": progress.best, "best_by": best_by}
