"""What a results file says its configuration is: the tracker's canonical id, the short name of
the shipped weights it ran, and the task options that are part of its identity. Read alike by
the writer (file names, the overwrite guard), the leaderboards, ``compare`` and the figures."""
from __future__ import annotations

from typing import Any, Mapping

from doabench.envs.registry import get_task_spec
from doabench.envs.sources import recorded_identity
from doabench.errors import DoabenchError
from doabench.trackers.registry import weights_name


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


def results_task_options(results: Mapping[str, Any]) -> dict[str, Any]:
    """The task options that are part of a run's identity (``task.options`` of its results; for a
    file written before results held them, read back from ``task.source``)."""
    task = results.get("task") or {}
    if isinstance(task.get("options"), Mapping):
        return dict(task["options"])
    try:
        spec = get_task_spec(str(task.get("id")))
    except DoabenchError:  # a plug-in task not installed here: its source alone says it
        spec = None
    return recorded_identity(spec, str(task.get("kind")), task.get("source") or {})


def results_weights_name(results: Mapping[str, Any]) -> str | None:
    """The short name of the shipped weights a run used (``tracker.weights_name``; for a file
    written before it was recorded, the name its weights hash has among the tracker's shipped
    weights here), None for other weights or none."""
    tracker = results.get("tracker") or {}
    if tracker.get("weights_name"):
        return str(tracker["weights_name"])
    return weights_name(canonical_id(dict(results)), tracker.get("weights_hash"))
