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
--compact``), for runs whose state is committed between sessions: the latest weights stay float32
and exact; each Adam moment is stored in 8 bits per value, in blocks of 256 values on a logarithmic
scale of the block's own range (first moment: sign and 127 levels over 24 octaves below the
block's largest magnitude; second moment: 255 levels over 48 octaves), and the best epoch's
weights, where they are not the latest, as their 8-bit difference from the latest weights (linear,
per block of 256). About a third of a float32 state (Cross3D 32x64: 90 -> 34 MB without best
weights, 39 MB with them). A resume continues from the decoded moments (relative error at most 7 %
per value, the first moment's forgotten within tens of steps); docs/training.md gives the measured
effect on the next update. Best weights decode to within 1/254 of the block's largest difference.

Restoring the RNG states matters only for code that draws from the global generators: training
items are seeded from ``(base_seed, epoch, item)`` anyway, so an epoch is the same whether it runs
straight or after ``--resume``.
"""
from __future__ import annotations

import json
import math
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

    compact = state.get("compact") == "log8"
    tensors: dict[str, torch.Tensor] = {f"model/{k}": v.detach().cpu().contiguous() for k, v in state["model"].items()}
    if state.get("best_model") is not None:
        for k, v in state["best_model"].items():
            latest = state["model"].get(k)
            if compact and v.is_floating_point() and latest is not None and latest.shape == v.shape:
                for part, t in encode_delta8(v.cpu(), latest.cpu()).items():
                    tensors[f"best8/{k}/{part}"] = t.contiguous()
            else:
                tensors[f"best/{k}"] = v.detach().cpu().contiguous()
    optim = state["optimizer"]
    scalars: dict[str, dict[str, Any]] = {}
    shapes: dict[str, list[int]] = {}
    for index, per_param in optim["state"].items():
        scalars[str(index)] = {}
        for key, value in per_param.items():
            if isinstance(value, torch.Tensor) and key != "step":
                if compact and value.is_floating_point():
                    for part, t in encode_log8(value.cpu(), signed=key != "exp_avg_sq").items():
                        tensors[f"optim8/{index}/{key}/{part}"] = t.contiguous()
                    shapes[f"{index}/{key}"] = list(value.shape)
                else:
                    tensors[f"optim/{index}/{key}"] = value.detach().cpu().contiguous()
            else:
                scalars[str(index)][key] = float(value)  # Adam's step count
    tensors["rng/torch"] = state["rng"]["torch"].clone()
    plain = {k: v for k, v in state.items() if k not in ("model", "best_model", "optimizer", "rng")}
    plain.update(format=FORMAT, optimizer_groups=optim["param_groups"], optimizer_scalars=scalars,
                 rng_numpy=_numpy_state_json(state["rng"]["numpy"]),
                 rng_python=_python_state_json(state["rng"]["python"]))
    if shapes:
        plain["moment_shapes"] = shapes
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
    try:
        for key, shape in (plain.get("moment_shapes") or {}).items():
            index, name = key.split("/", 1)
            optim_state.setdefault(int(index), {})[name] = decode_log8(
                tensors[f"optim8/{key}/codes"], tensors[f"optim8/{key}/top"], tuple(shape), signed=name != "exp_avg_sq")
        best = _split(tensors, "best/")
        for key in {k.rsplit("/", 1)[0] for k in _split(tensors, "best8/")}:
            best[key] = decode_delta8(tensors[f"best8/{key}/codes"], tensors[f"best8/{key}/scale"], model[key])
    except (KeyError, ValueError, RuntimeError) as exc:
        raise InputError(f"checkpoint {path} has a damaged compact state ({type(exc).__name__}: {exc})") from None
    name, keys, pos, has_gauss, gauss = plain["rng_numpy"]
    version, internal, py_gauss = plain["rng_python"]
    state = {k: v for k, v in plain.items() if k not in ("optimizer_groups", "optimizer_scalars", "rng_numpy",
                                                         "rng_python")}
    state.update(model=model, best_model=best or None,
                 optimizer={"state": optim_state, "param_groups": plain["optimizer_groups"]},
                 rng={"torch": tensors["rng/torch"], "numpy": (name, np.asarray(keys, dtype=np.uint32), pos,
                                                               has_gauss, gauss),
                      "python": (version, tuple(internal), py_gauss)})
    return state


BLOCK = 256  # values per quantisation block of a compact state
_FIRST_OCTAVES, _SECOND_OCTAVES = 24.0, 48.0


def _blocks(t: torch.Tensor) -> torch.Tensor:
    """``t`` flattened, zero-padded to whole blocks: ``(n_blocks, BLOCK)`` float32."""
    flat = t.detach().float().reshape(-1)
    return torch.nn.functional.pad(flat, (0, (-flat.numel()) % BLOCK)).reshape(-1, BLOCK)


def encode_log8(t: torch.Tensor, signed: bool) -> dict[str, torch.Tensor]:
    """8-bit codes of ``t`` on a per-block logarithmic scale: ``codes`` (int8 signed, uint8 not;
    0 is zero) and ``top`` ``(n_blocks,)`` (log2 of the block's largest magnitude)."""
    x = _blocks(t)
    levels, octaves = (127, _FIRST_OCTAVES) if signed else (255, _SECOND_OCTAVES)
    mag = x.abs()
    top = torch.log2(mag.amax(dim=1).clamp_min(torch.finfo(torch.float32).tiny))
    step = octaves / (levels - 1)
    level = torch.round((torch.log2(mag.clamp_min(torch.finfo(torch.float32).tiny)) - (top[:, None] - octaves)) / step)
    code = torch.where(level < 0, torch.zeros_like(level), level.clamp(max=levels - 1) + 1)
    code = torch.where(mag > 0, code, torch.zeros_like(code))
    if signed:
        return {"codes": (code * torch.sign(x)).to(torch.int8), "top": top}
    return {"codes": code.to(torch.uint8), "top": top}


def decode_log8(codes: torch.Tensor, top: torch.Tensor, shape: tuple[int, ...], signed: bool) -> torch.Tensor:
    """Inverse of :func:`encode_log8`: float32 of ``shape``."""
    levels, octaves = (127, _FIRST_OCTAVES) if signed else (255, _SECOND_OCTAVES)
    c = codes.to(torch.float32)
    mag = torch.exp2(top[:, None] - octaves + (c.abs() - 1) * (octaves / (levels - 1)))
    x = torch.where(c == 0, torch.zeros_like(mag), mag * torch.sign(c))
    n = math.prod(shape)
    return x.reshape(-1)[:n].reshape(shape)


def encode_delta8(t: torch.Tensor, reference: torch.Tensor) -> dict[str, torch.Tensor]:
    """``t - reference`` in 8 bits per value, linear per block: ``codes`` (int8) and ``scale``."""
    d = _blocks(t.float() - reference.float())
    scale = d.abs().amax(dim=1) / 127
    codes = torch.round(d / scale.clamp_min(torch.finfo(torch.float32).tiny)[:, None]).clamp(-127, 127)
    return {"codes": codes.to(torch.int8), "scale": scale}


def decode_delta8(codes: torch.Tensor, scale: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    d = (codes.to(torch.float32) * scale[:, None]).reshape(-1)[:reference.numel()].reshape(reference.shape)
    return reference.float() + d


def compact_checkpoint(path: str | Path) -> tuple[int, int]:
    """Rewrite the checkpoint at ``path`` in place (atomically) as a compact state (see the module
    docstring); returns the file sizes before and after."""
    path = Path(path)
    before = path.stat().st_size if path.is_file() else 0
    state = load_checkpoint(path)
    state["compact"] = "log8"
    save_checkpoint(path, state)
    return before, path.stat().st_size


def best_weights(state: dict[str, Any]) -> dict[str, torch.Tensor]:
    """The best epoch's weights of a loaded state (the latest ones when they are the best)."""
    return state["best_model"] if state.get("best_model") is not None else state["model"]
