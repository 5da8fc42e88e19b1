"""What a results file says its configuration is: the tracker's canonical id, the short name of
the shipped weights it ran, and the task options that are part of its identity. Read alike by
the writer (file names, the overwrite guard), the leaderboards, ``compare`` and the figures.

A results file is data, often someone else's: reading one imports nothing it names. Tracker ids
stay text (no tracker is resolved or built), the weights' name is the one the file records, task
ids are looked up among the registered tasks only, and a task kind only among those registered
or doabench's own."""
from __future__ import annotations

from typing import Any, Mapping

from doabench.envs.registry import get_task_spec
from doabench.envs.sources import recorded_identity
from doabench.envs.spec import TaskSpec
from doabench.errors import DoabenchError

#: The names of the weights that shipped before results files recorded ``tracker.weights_name``,
#: by tracker id and SHA-256 (their names in ``baselines/weights/catalog.json``): how a file of
#: that time is named. Every file written since carries its weights' name itself.
NAMES_BEFORE_RECORDING: dict[tuple[str, str], str] = {
    ("cross3d:16x32", "8d1eef915b2a8edcce9090c8d4b6b73e182fb3517add31c12b24dfd7799c0a4c"): "paper",
    ("cross3d:16x32", "8ce3ea54bcd7cef2fff9bbe32e0ded4137d780bcf86fe6adc67c1340722be8cb"): "moving",
    ("cross3d:16x32", "68ad5339d4e56fef1963f31bc3bfc19633011ede09174f9d809a67fd81975124"): "paper-v3",
    ("cross3d:8x16", "6a2a5ef6fb3bba7899a08cea325f48df674a86b9b92df5310e00009239a798d1"): "paper",
    ("cross3d:8x16", "fe8c0ebdf1de4776a3de4862f404ed94ab09c72ea058fd849c65c7053679da2d"): "moving",
    ("cross3d:4x8", "f7b287c60ff0498a910a1c06cad1d82c5f1d756f9d2e259c5645b0c59f527997"): "paper",
    ("gcc-cnn1d", "16f53834efc3d28ddbd609285b79ce48516205c2acb207afd45856bd0153e94a"): "paper",
    ("max-cnn1d:64x128", "cf1d9a2d1df2181bc6854198c17922edb7116eddbee50e6b6fca9c83fa16507a"): "paper",
    ("seldnet", "6c2f53a8bf7b1d4c377bc7b6bc4afa11df793bc0a0a45641cfa929a4e2e358e4"): "paper",
    ("spec-cnn2d", "b5a8266e795d01c44b6bd370424d2dca4961fcae1b6d84ccbe8470e9bf003946"): "paper",
}


def canonical_id(results: dict[str, Any]) -> str:
    """The tracker id a results file is shown and ranked under. Files written since ids became
    canonical (``doabench.trackers.registry.canonical_tracker``) carry it as ``tracker.id``; an
    older file's bare id of a tracker whose spec is its map resolution gets the resolution it ran
    at (``cross3d`` -> ``cross3d:16x32``)."""
    tracker = results.get("tracker") or {}
    text = str(tracker.get("id") or tracker.get("name"))
    resolution = tracker.get("resolution")
    in_id = tracker.get("resolution_in_id", resolution is not None)
    if ":" not in text and in_id and resolution:
        return f"{text}:{resolution}"
    return text


def recorded_task_spec(task_id: str) -> TaskSpec | None:
    """The spec of a task id read from a results file: a registered task, else None. A prefixed id
    (``file:data.h5``) is not resolved: that would open the file it names or load the prefix's
    plug-in."""
    if ":" in str(task_id):
        return None
    try:
        return get_task_spec(str(task_id))
    except DoabenchError:
        return None


def results_task_options(results: Mapping[str, Any]) -> dict[str, Any]:
    """The task options that are part of a run's identity (``task.options`` of its results; for a
    file written before results held them, read back from ``task.source``)."""
    task = results.get("task") or {}
    if isinstance(task.get("options"), Mapping):
        return dict(task["options"])
    spec = recorded_task_spec(str(task.get("id")))  # None: a task not registered here; its source alone says it
    return recorded_identity(spec, str(task.get("kind")), task.get("source") or {})


def results_weights_name(results: Mapping[str, Any]) -> str | None:
    """The short name of the shipped weights a run used, as its file records it
    (``tracker.weights_name``; for a file written before it was recorded, the name
    :data:`NAMES_BEFORE_RECORDING` gives its weights), None for other weights or none. Read, never
    derived from the tracker: no tracker is resolved."""
    tracker = results.get("tracker") or {}
    if "weights_name" in tracker:
        name = tracker["weights_name"]
        return str(name) if isinstance(name, str) and name else None
    digest = tracker.get("weights_hash")
    return NAMES_BEFORE_RECORDING.get((canonical_id(dict(results)), str(digest))) if digest else None
