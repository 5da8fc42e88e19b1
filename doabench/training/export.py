"""Export a training run's checkpoint as a shippable weights file with full metadata."""
from __future__ import annotations

import platform
from pathlib import Path
from typing import Any

import torch

from doabench.geometry import resolution_text
from doabench.errors import ConfigError
from doabench.training import checkpoint as ckpt
from doabench.training.losses import describe_loss
from doabench.training.protocol import check_trainable, training_observations


def _observations(tracker: Any) -> dict[str, Any]:
    """``{"observations": spec}``: what the tracker trained on, stored whole."""
    return {"observations": training_observations(tracker).to_dict()}


def training_metadata(state: dict[str, Any], tracker: Any, which: str, tracker_id: str | None = None) -> dict[str, Any]:
    """What a weights file records about how it was trained (JSON-serialisable)."""
    from doabench._version import __version__
    from doabench.envs.registry import get_task_spec

    spec = get_task_spec(state["task"])
    history = state["history"]
    epoch = int(state.get("best_epoch") or state["epoch"]) if which == "best" else int(state["epoch"])
    row = next((h for h in history if h["epoch"] == epoch), history[-1] if history else {})
    meta = {
        "tracker": tracker_id or state["tracker"],
        "resolution": resolution_text(tracker.resolution),
        "array": spec.array,
        **_observations(tracker),
        "doabench_version": __version__,
        "torch_version": torch.__version__,
        "training": {
            "task": spec.id, "task_version": int(state.get("task_version") or spec.version), "recipe": state["recipe"],
            "checkpoint": which, "epochs_completed": epoch,
            "trajectories_seen": int(row.get("trajectories_seen") or state["trajectories_seen"]),
            "distinct_trajectories": int(row.get("trajectories_seen") or state["trajectories_seen"])
            if state["recipe"].get("data") == "simulate" else (row.get("n_cache") or None),
            "compute_s": round(float(row.get("compute_s") or state["compute_s"]), 1),
            "precision": precision_record(state),
            "hardware": f"{state.get('device', 'cpu')} ({platform.machine()}), "
                        f"{state.get('threads', '?')} torch threads",
            "cached_trajectories": row.get("n_cache") or None,
            "loss": describe_loss(float(state["recipe"].get("delta_loss") or 0.0)),
            "optimizer": "Adam",
            "validation": {k: row.get(k) for k in ("val_loss", "val_rmsae_all", "val_rmsae_nonsilent", "val_rmsae_held")
                           if row.get(k) is not None},
            "best_epoch_by": (state.get("best_by") or "val_rmsae_all") if which == "best" else None,
            "validation_set": "fixed held-out-speaker trajectories (10% of the speakers), scene SNR",
        },
    }
    start = state.get("initial_weights")
    if start:  # a fine-tuned model: what it started from, and the totals over both runs
        meta["training"]["fine_tuned_from"] = start
        before = start.get("training") or {}
        for key in ("trajectories_seen", "compute_s"):
            if before.get(key) is not None:
                meta["training"][f"{key}_total"] = round(meta["training"][key] + float(before[key]), 1)
    return meta


def precision_record(state: dict[str, Any]) -> str:
    """The training precision of a run: ``"bf16"``, or per stretch of epochs where a resumed run
    changed it (``"bf16 (epochs 1-17), fp32 (epoch 18)"``, e.g. resumed on a CPU without bf16)."""
    saved = state.get("precision", "float32")
    stretches: list[list[Any]] = []  # [precision, first epoch, last epoch]
    for row in state.get("history") or []:
        precision = row.get("precision") or saved
        if stretches and stretches[-1][0] == precision:
            stretches[-1][2] = row["epoch"]
        else:
            stretches.append([precision, row["epoch"], row["epoch"]])
    if len(stretches) <= 1:
        return stretches[0][0] if stretches else saved
    return ", ".join(f"{p} (epoch {a})" if a == b else f"{p} (epochs {a}-{b})" for p, a, b in stretches)


def export_weights(run_dir: str | Path, out_path: str | Path, which: str = "best", tracker: Any = None,
                   tracker_id: str | None = None, dtype: str = "float32") -> Path:
    """Load the best or the latest weights of ``run_dir``'s checkpoint into the tracker and save them.

    ``tracker_id`` (default: the id the run was trained with) builds the tracker when ``tracker``
    is not given; its network must have the same parameter names and shapes. ``dtype="float16"``
    stores half-precision weights (half the file size; loading converts them back to float32).
    """
    if dtype not in ("float32", "float16"):
        raise ConfigError(f"export dtype must be float32 or float16, got {dtype!r}")
    from doabench.trackers.registry import make_tracker

    if which not in ("best", "latest"):
        raise ConfigError(f"export which must be best or latest, got {which!r}")
    state = ckpt.load_checkpoint(Path(run_dir) / ckpt.LATEST)
    config = Path(run_dir) / "config.json"
    if "threads" not in state and config.exists():  # runs started before checkpoints recorded it
        import json

        state["threads"] = json.loads(config.read_text()).get("threads")
    tracker_id = tracker_id or state["tracker"]
    if tracker is None:  # built with the options the run trained with (what it reads may depend on them)
        options = dict(state.get("tracker_options") or {})
        if _takes_weights(tracker_id):
            options["weights"] = "random"
        tracker = make_tracker(tracker_id, **options)
    check_trainable(tracker, tracker_id)
    trained_on = state.get("observations")
    reads = training_observations(tracker)
    if trained_on is not None and trained_on != reads.to_dict():
        raise ConfigError(f"{run_dir} was trained on observations {trained_on}, which tracker {tracker_id!r} "
                          f"does not read ({reads}); export it with the tracker it trained")
    tracker.network.load_state_dict(ckpt.best_weights(state) if which == "best" else state["model"])
    tracker.network.eval()
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    meta = training_metadata(state, tracker, which, tracker_id)
    meta["training"]["stored_dtype"] = dtype
    if dtype == "float16":
        tracker.network.half()
    try:
        tracker.save_weights(out_path, meta)
    finally:
        tracker.network.float()
    return out_path


def _takes_weights(tracker_id: str) -> bool:
    """True when the tracker's constructor accepts ``weights=`` (so shipped weights are not loaded first)."""
    import inspect

    from doabench.trackers.registry import resolve_tracker

    cls, _, _ = resolve_tracker(tracker_id)
    return "weights" in inspect.signature(cls.__init__).parameters
