"""Training checkpoints: model, optimizer, RNG states and curriculum position, written atomically.

``checkpoint.pt`` (latest, every epoch) and ``best.pt`` (the best validation RMSAE so far) hold::

    {"format", "epoch" (epochs completed), "model", "optimizer", "rng": {"torch", "numpy", "python"},
     "recipe", "tracker", "task", "history" (per-epoch rows), "best", "compute_s", "trajectories_seen"}

Restoring the RNG states matters only for code that draws from the global generators: training
items are seeded from ``(base_seed, epoch, item)`` anyway, so an epoch is the same whether it runs
straight or after ``--resume``.
"""
from __future__ import annotations

import random
from pathlib import Path
from typing import Any

import numpy as np
import torch

from doabench.errors import InputError, NotFoundError
from doabench.results.files import atomic_path

FORMAT = 1
LATEST = "checkpoint.pt"
BEST = "best.pt"


def rng_state() -> dict[str, Any]:
    return {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()}


def set_rng_state(state: dict[str, Any]) -> None:
    torch.set_rng_state(state["torch"])
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])


def save_checkpoint(path: str | Path, state: dict[str, Any]) -> Path:
    """Write ``state`` (see the module docstring) atomically to ``path``."""
    with atomic_path(path, suffix=".pt") as tmp:
        torch.save({"format": FORMAT, **state}, tmp)
    return Path(path)


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    if not path.is_file():
        raise NotFoundError(f"no checkpoint at {path}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # a truncated or foreign file
        raise InputError(f"cannot read checkpoint {path}: {type(exc).__name__}: {exc}") from None
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        raise InputError(f"{path} is not a doabench training checkpoint (format {FORMAT})")
    return state
