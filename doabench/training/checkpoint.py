"""Training checkpoints that load without executing anything: one safetensors file per run.

``checkpoint.safetensors`` (rewritten atomically after every epoch) holds the whole run state:

* tensors: ``model/<name>`` (latest weights), ``best/<name>`` (weights of the epoch with the
  lowest validation RMSAE; absent when that is the latest epoch, which the metadata says),
  ``optim/<param index>/<key>`` (Adam moments, float32 so a resume is exact) and
  ``rng/torch`` (torch's generator state, uint8);
* metadata ``doabench_state``: JSON with every plain value: ``format``, ``epoch`` (epochs
  completed), ``best_epoch``, the optimiser's param groups and per-parameter scalars (``step``),
  the numpy and python RNG states, ``recipe``, ``tracker``, ``task``, ``history`` (per-epoch
  rows), ``best``, ``compute_s``, ``trajectories_seen``, ``precision``, ``threads``.

Loading reads tensors and JSON only (no pickle), so a crafted file cannot run code; missing
keys, wrong types and non-finite weights are refused with one line. A state is a plain dict::

    {"epoch", "model": state_dict, "best_model": state_dict | None, "optimizer": state_dict,
     "rng": {"torch", "numpy", "python"}, ...the JSON values above}

**Compact states for committing** (:func:`compact_checkpoint`, ``doabench train --out RUN
--compact``): the Adam moments and the best epoch's weights stored as bfloat16, the latest
weights stay float32. About 40 % smaller (Cross3D 16x32: 27 -> 17 MB; the 1D CNNs' moments are
most of their 90-180 MB), for runs whose state is committed between sessions. A resume from it
continues with the moments rounded to bfloat16 (Adam casts them back to float32); the best
weights are only exported, where bfloat16 rounding moved scores by under 0.01 deg.

Restoring the RNG states matters only for code that draws from the global generators: training
items are seeded from ``(base_seed, epoch, item)`` anyway, so an epoch is the same whether it runs
straight or after ``--resume``.
"""
from __future__ import annotations

import json
import random
from pathlib import Path
from typing import Any

import numpy as np
import torch

from doabench.errors import InputError, NotFoundError
from doabench.files import atomic_path

FORMAT = 2
LATEST = "checkpoint.safetensors"
_META_KEY = "doabench_state"
_REQUIRED = ("epoch", "optimizer_groups", "optimizer_scalars", "rng_numpy", "rng_python", "recipe", "tracker",
             "task", "history", "best", "compute_s", "trajectories_seen")


def rng_state() -> dict[str, Any]:
    return {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()}


def set_rng_state(state: dict[str, Any]) -> None:
    torch.set_rng_state(state["torch"])
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])


def _numpy_state_json(state: tuple) -> list:
    name, keys, pos, has_gauss, gauss = state
    return [name, np.asarray(keys, dtype=np.uint32).tolist(), int(pos), int(has_gauss), float(gauss)]


def _python_state_json(state: tuple) -> list:
    version, internal, gauss = state
    return [version, list(internal), gauss]


def save_checkpoint(path: str | Path, state: dict[str, Any]) -> Path:
    """Write ``state`` (see the module docstring) atomically to ``path``."""
    from safetensors.torch import save_file

    tensors: dict[str, torch.Tensor] = {f"model/{k}": v.detach().cpu().contiguous() for k, v in state["model"].items()}
    if state.get("best_model") is not None:
        tensors.update({f"best/{k}": v.detach().cpu().contiguous() for k, v in state["best_model"].items()})
    optim = state["optimizer"]
    scalars: dict[str, dict[str, Any]] = {}
    for index, per_param in optim["state"].items():
        scalars[str(index)] = {}
        for key, value in per_param.items():
            if isinstance(value, torch.Tensor) and key != "step":
                tensors[f"optim/{index}/{key}"] = value.detach().cpu().contiguous()
            else:
                scalars[str(index)][key] = float(value)  # Adam's step count
    tensors["rng/torch"] = state["rng"]["torch"].clone()
    plain = {k: v for k, v in state.items() if k not in ("model", "best_model", "optimizer", "rng")}
    plain.update(format=FORMAT, optimizer_groups=optim["param_groups"], optimizer_scalars=scalars,
                 rng_numpy=_numpy_state_json(state["rng"]["numpy"]),
                 rng_python=_python_state_json(state["rng"]["python"]))
    with atomic_path(path, suffix=".safetensors") as tmp:
        save_file(tensors, str(tmp), metadata={_META_KEY: json.dumps(plain)})
    return Path(path)


def _split(tensors: dict[str, torch.Tensor], prefix: str) -> dict[str, torch.Tensor]:
    n = len(prefix)
    return {k[n:]: v for k, v in tensors.items() if k.startswith(prefix)}


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    """Read a checkpoint written by :func:`save_checkpoint`; one-line InputError when it is not one."""
    from safetensors import safe_open

    path = Path(path)
    if not path.is_file():
        raise NotFoundError(f"no checkpoint at {path}")
    try:
        with safe_open(str(path), framework="pt") as f:
            meta = f.metadata() or {}
            tensors = {k: f.get_tensor(k) for k in f.keys()}
        plain = json.loads(meta[_META_KEY])
    except Exception as exc:  # truncated, foreign or corrupt file
        raise InputError(f"cannot read checkpoint {path}: not a doabench training checkpoint "
                         f"({type(exc).__name__})") from None
    if not isinstance(plain, dict) or plain.get("format") != FORMAT:
        raise InputError(f"{path} is not a doabench training checkpoint (format {FORMAT})")
    missing = [k for k in _REQUIRED if k not in plain]
    if missing or "rng/torch" not in tensors:
        raise InputError(f"checkpoint {path} is missing {', '.join(missing or ['rng/torch'])}")
    model = _split(tensors, "model/")
    bad = [k for k, v in model.items() if v.is_floating_point() and not bool(torch.isfinite(v).all())]
    if not model or bad:
        raise InputError(f"checkpoint {path} has {'no weights' if not model else 'non-finite weights in ' + bad[0]}")
    optim_state: dict[int, dict[str, Any]] = {}
    for index, values in plain["optimizer_scalars"].items():
        optim_state[int(index)] = {k: torch.tensor(float(v), dtype=torch.float32) for k, v in values.items()}
    for key, value in _split(tensors, "optim/").items():
        index, name = key.split("/", 1)
        optim_state.setdefault(int(index), {})[name] = value
    name, keys, pos, has_gauss, gauss = plain["rng_numpy"]
    version, internal, py_gauss = plain["rng_python"]
    state = {k: v for k, v in plain.items() if k not in ("optimizer_groups", "optimizer_scalars", "rng_numpy",
                                                         "rng_python")}
    best = _split(tensors, "best/")
    state.update(model=model, best_model=best or None,
                 optimizer={"state": optim_state, "param_groups": plain["optimizer_groups"]},
                 rng={"torch": tensors["rng/torch"], "numpy": (name, np.asarray(keys, dtype=np.uint32), pos,
                                                               has_gauss, gauss),
                      "python": (version, tuple(internal), py_gauss)})
    return state


def compact_checkpoint(path: str | Path) -> tuple[int, int]:
    """Rewrite the checkpoint at ``path`` in place (atomically) with its Adam moments and best
    weights in bfloat16 (see the module docstring); returns the file sizes before and after."""
    path = Path(path)
    before = path.stat().st_size if path.is_file() else 0
    state = load_checkpoint(path)

    def half(t: torch.Tensor) -> torch.Tensor:
        return t.to(torch.bfloat16) if t.is_floating_point() else t

    for per_param in state["optimizer"]["state"].values():
        for key, value in per_param.items():
            if isinstance(value, torch.Tensor) and key != "step":
                per_param[key] = half(value)
    if state.get("best_model") is not None:
        state["best_model"] = {k: half(v) for k, v in state["best_model"].items()}
    state["compact"] = True
    save_checkpoint(path, state)
    return before, path.stat().st_size


def best_weights(state: dict[str, Any]) -> dict[str, torch.Tensor]:
    """The best epoch's weights of a loaded state (the latest ones when they are the best)."""
    return state["best_model"] if state.get("best_model") is not None else state["model"]
