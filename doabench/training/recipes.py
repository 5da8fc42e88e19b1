"""Training recipes: the paper's (section IV-C) and a CPU preset that fits a small machine.

A recipe is a list of curriculum :class:`Phase` objects (from which epoch on: SNR range, batch size,
learning rate) plus the epoch size and count and where trajectories come from:

* ``paper``: every training trajectory simulated on the fly (``data = "simulate"``), 80 epochs of
  585 trajectories of 20 s; SNR 30 dB, batch 5, lr 1e-4 for epochs 0-19, then SNR 5-30 dB,
  batch 10, lr 1e-5. Meant for a GPU simulator (gpuRIR).
* ``cpu``: simulation is the expensive part on a CPU (about 1 s or more per 20 s trajectory), so
  ``cache_size`` noise-free reverberant trajectories are simulated once (``data = "cache"``) and
  every training item draws one of them and adds fresh white noise at the phase's SNR. Smaller
  epochs, fewer of them, and the same curriculum shape compressed in time (see docs/training.md).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Iterable

from doabench.errors import ConfigError

DATA_MODES = ("simulate", "cache")


@dataclass(frozen=True)
class Phase:
    """Curriculum phase, active from ``start_epoch`` (0-based) until the next phase starts."""

    start_epoch: int
    snr: tuple[float, float]
    batch_size: int
    lr: float

    def to_dict(self) -> dict[str, Any]:
        return {"start_epoch": self.start_epoch, "snr": list(self.snr), "batch_size": self.batch_size, "lr": self.lr}


@dataclass(frozen=True)
class Recipe:
    """Everything that decides what a training run sees (see the module docstring)."""

    name: str
    epochs: int
    trajectories_per_epoch: int
    phases: tuple[Phase, ...]
    data: str = "simulate"
    cache_size: int = 0            # cached trajectories ("cache" mode)
    val_trajectories: int = 30     # fixed validation trajectories (held-out speakers)
    val_speaker_fraction: float = 0.1
    t60: tuple[float, float] | None = None  # None: the task's range
    duration_s: float = 20.0
    num_workers: int = 0
    seed: int = 0
    delta_loss: float = 0.0        # weight of the frame-to-frame change loss (doabench.training.losses)
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.data not in DATA_MODES:
            raise ConfigError(f"recipe data mode must be one of {', '.join(DATA_MODES)}, got {self.data!r}")
        if self.epochs < 1 or self.trajectories_per_epoch < 1:
            raise ConfigError("epochs and trajectories per epoch must be >= 1")
        if not self.phases or self.phases[0].start_epoch != 0:
            raise ConfigError("the first curriculum phase must start at epoch 0")
        starts = [p.start_epoch for p in self.phases]
        if starts != sorted(set(starts)):
            raise ConfigError(f"curriculum phases must start at increasing epochs, got {starts}")
        for p in self.phases:
            if p.batch_size < 1 or not p.lr > 0 or p.snr[0] > p.snr[1]:
                raise ConfigError(f"bad curriculum phase {p.to_dict()}")
        if self.data == "cache" and self.cache_size < 1:
            raise ConfigError("a cached-data recipe needs cache_size >= 1")
        if not 0 <= self.delta_loss < float("inf"):
            raise ConfigError(f"the frame-difference loss weight (--delta-loss) must be a number >= 0, got {self.delta_loss}")
        if not 0 < self.val_speaker_fraction < 1:
            raise ConfigError(f"val_speaker_fraction must be in (0, 1), got {self.val_speaker_fraction}")

    def phase(self, epoch: int) -> Phase:
        """The curriculum phase of 0-based ``epoch``."""
        current = self.phases[0]
        for p in self.phases:
            if epoch >= p.start_epoch:
                current = p
        return current

    def replace(self, **changes: Any) -> "Recipe":
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["phases"] = [p.to_dict() for p in self.phases]
        d["t60"] = None if self.t60 is None else list(self.t60)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Recipe":
        d = dict(d)
        d["phases"] = tuple(Phase(int(p["start_epoch"]), tuple(p["snr"]), int(p["batch_size"]), float(p["lr"]))
                            for p in d["phases"])
        d["t60"] = None if d.get("t60") is None else tuple(d["t60"])
        return cls(**d)


def paper_recipe() -> Recipe:
    """Section IV-C: 80 epochs x 585 fresh 20 s trajectories, Adam, the SNR curriculum."""
    return Recipe(
        name="paper", epochs=80, trajectories_per_epoch=585, data="simulate", num_workers=4,
        phases=(Phase(0, (30.0, 30.0), 5, 1e-4), Phase(20, (5.0, 30.0), 10, 1e-5)),
    )


def cpu_recipe() -> Recipe:
    """About an hour per model on 2 CPU cores: 20 epochs of 150 items drawn from up to 600 cached
    trajectories (3000 items in all, 6% of the paper's 46800).

    Same curriculum shape as the paper (SNR 30 dB and batch 5 first, then 5-30 dB and batch 10),
    switching halfway. The learning rates are 3x the paper's (3e-4, then 1e-4) because the run
    takes about a tenth of the paper's optimiser steps before the switch.
    """
    return Recipe(
        name="cpu", epochs=20, trajectories_per_epoch=150, data="cache", cache_size=600, val_trajectories=24,
        phases=(Phase(0, (30.0, 30.0), 5, 3e-4), Phase(10, (5.0, 30.0), 10, 1e-4)),
    )


def finetune_recipe() -> Recipe:
    """Continue a trained model on a changed training distribution (beyond the paper): 10 epochs
    of 585 fresh trajectories at the paper's second phase (SNR 5-30 dB, batch 10), lr 3e-5 for
    five epochs, then the paper's final 1e-5. Start it from shipped weights (``--tracker
    cross3d:16x32`` without ``weights=random``); the weights file records what it started from.
    """
    return Recipe(
        name="finetune", epochs=10, trajectories_per_epoch=585, data="simulate", num_workers=4,
        phases=(Phase(0, (5.0, 30.0), 10, 3e-5), Phase(5, (5.0, 30.0), 10, 1e-5)),
    )


PRESETS = {"paper": paper_recipe, "cpu": cpu_recipe, "finetune": finetune_recipe}


def get_recipe(name: str) -> Recipe:
    if name not in PRESETS:
        raise ConfigError(f"unknown training preset {name!r} (choose from {', '.join(PRESETS)})")
    return PRESETS[name]()


# The `doabench train` options that set part of a recipe, each with what it sets. A resumed run
# keeps the recipe it started with (only --epochs, and --switch-epoch for a switch still ahead, may
# change), so an option given with --resume must agree with the run's own recipe: silently ignoring
# it would train something else than asked.
RECIPE_OPTIONS: dict[str, Callable[[Recipe], Any]] = {
    "--preset": lambda r: r.name,
    "--seed": lambda r: r.seed,
    "--epoch-size": lambda r: r.trajectories_per_epoch,
    "--cache-size": lambda r: r.cache_size,
    "--val-trajectories": lambda r: r.val_trajectories,
    "--switch-epoch": lambda r: ",".join(str(p.start_epoch) for p in r.phases[1:]),
    "--lr": lambda r: ",".join(f"{p.lr:g}" for p in r.phases),
    "--delta-loss": lambda r: r.delta_loss,
}


def resume_conflicts(saved: Recipe, requested: Recipe, given: Iterable[str], epochs_done: int = 0) -> list[str]:
    """For each recipe option in ``given`` (command-line flags of :data:`RECIPE_OPTIONS`) whose
    value in ``requested`` differs from the resumed run's ``saved`` recipe: ``"--lr 0.001,0.0001
    (the run's: 0.0001,1e-05)"``. Empty when the options agree with the run.

    ``--switch-epoch`` may differ while neither the run's switch nor the asked one lies in the
    ``epochs_done`` epochs already trained: the history stays true, only the schedule ahead moves
    (how a run is shortened to the time it has)."""
    conflicts = []
    for flag in given:
        value = RECIPE_OPTIONS[flag]
        if value(requested) == value(saved):
            continue
        if flag == "--switch-epoch" and switch_still_ahead(saved, requested, epochs_done):
            continue
        conflicts.append(f"{flag} {value(requested)} (the run's: {value(saved)})")
    return conflicts


def switch_still_ahead(saved: Recipe, requested: Recipe, epochs_done: int) -> bool:
    """Whether the phase switches of ``saved`` and ``requested`` both start at or after
    ``epochs_done`` (the epochs already trained), with the same phases otherwise."""
    if len(saved.phases) != len(requested.phases) or len(saved.phases) < 2:
        return False
    same_otherwise = all(replace(a, start_epoch=0) == replace(b, start_epoch=0)
                         for a, b in zip(saved.phases, requested.phases))
    starts = [p.start_epoch for p in saved.phases[1:]] + [p.start_epoch for p in requested.phases[1:]]
    return same_otherwise and min(starts) >= epochs_done


def resumed_phases(saved: Recipe, requested: Recipe, given: Iterable[str], epochs_done: int) -> Recipe:
    """``saved`` with the phase switches of ``requested`` when ``--switch-epoch`` was given and
    may move (:func:`switch_still_ahead`); ``saved`` otherwise."""
    if "--switch-epoch" in given and switch_still_ahead(saved, requested, epochs_done):
        return saved.replace(phases=requested.phases)
    return saved
