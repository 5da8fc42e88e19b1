"""What a results file says its configuration is: the tracker's canonical id, the short name of
the shipped weights it ran, the observations it read (their SRP delays) and the task options that
are part of its identity, as the current schema holds them (an older file is read through
:mod:`doabench.results.upgrade` first). Read alike by
the writer (file names, the overwrite guard), the leaderboards, ``compare`` and the figures.

A results file is data, often someone else's: reading one imports nothing it names. Tracker ids
stay text (no tracker is resolved or built), the weights' name is the one the file records, task
ids are looked up among the registered tasks only, and a task kind only among those registered
or doabench's own."""
from __future__ import annotations

from typing import Any, Mapping

from doabench.envs.registry import get_task_spec
from doabench.envs.spec import TaskSpec
from doabench.errors import ConfigError, DoabenchError
from doabench.features.spec import ObservationSpec


def canonical_id(results: Mapping[str, Any]) -> str:
    """The tracker id a results file is shown and ranked under: its ``tracker.id``, canonical
    (``doabench.trackers.registry.canonical_tracker``; an older file's is made so by
    :mod:`doabench.results.upgrade`)."""
    tracker = results.get("tracker") or {}
    return str(tracker.get("id") or tracker.get("name"))


def results_observations(results: Mapping[str, Any]) -> ObservationSpec:
    """The observations a run's tracker read (``observations``, read back with
    ``ObservationSpec.from_dict``); a one-line ConfigError for a file without a readable one."""
    stored = results.get("observations")
    if not isinstance(stored, Mapping):
        raise ConfigError("the results hold no observations block")
    return ObservationSpec.from_dict(stored)


def results_delays(results: Mapping[str, Any]) -> str:
    """The SRP delay mode a run used (its observations'; ``nearest`` where they hold none)."""
    if not isinstance(results.get("observations"), Mapping):
        return "nearest"
    return results_observations(results).delays or "nearest"


def results_kinds(results: Mapping[str, Any]) -> list[str]:
    """The names of the observation kinds a run's tracker read, in order (none where the results
    hold no observations)."""
    if not isinstance(results.get("observations"), Mapping):
        return []
    return [str(getattr(kind, "kind", kind)) for kind in results_observations(results).kinds]


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
    """The task options that are part of a run's identity (``task.options`` of its results)."""
    options = (results.get("task") or {}).get("options")
    return dict(options) if isinstance(options, Mapping) else {}


def results_weights_name(results: Mapping[str, Any]) -> str | None:
    """The short name of the shipped weights a run used, as its file records it
    (``tracker.weights_name``), None for other weights or none. Read, never derived from the
    tracker: no tracker is resolved."""
    name = (results.get("tracker") or {}).get("weights_name")
    return str(name) if isinstance(name, str) and name else None
