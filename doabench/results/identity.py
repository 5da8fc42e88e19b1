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
from doabench.features.kinds import BUILTIN_KINDS
from doabench.geometry import parse_resolution


def canonical_id(results: Mapping[str, Any]) -> str:
    """The tracker id a results file is shown and ranked under: its ``tracker.id``, canonical
    (``doabench.trackers.registry.canonical_tracker``; an older file's is made so by
    :mod:`doabench.results.upgrade`)."""
    tracker = results.get("tracker") or {}
    return str(tracker.get("id") or tracker.get("name"))


def _stored_kinds(results: Mapping[str, Any]) -> list[Mapping[str, Any]]:
    """The stored kinds of a run's ``observations`` block (``{"kind": NAME, ...its settings}``), read
    as data: a kind's name is never looked up among the feature kinds, which would load a plug-in."""
    stored = results.get("observations")
    kinds = stored.get("kinds") if isinstance(stored, Mapping) else None
    return [k for k in kinds if isinstance(k, Mapping)] if isinstance(kinds, list) else []


def results_kinds(results: Mapping[str, Any]) -> list[str]:
    """The names of the observation kinds a run's tracker read, in order (none where the results
    hold no observations)."""
    return [str(kind.get("kind")) for kind in _stored_kinds(results)]


def results_delays(results: Mapping[str, Any]) -> str:
    """The SRP delay mode a run used (its observations'; ``nearest`` where they hold none)."""
    return next((str(kind["delays"]) for kind in _stored_kinds(results) if kind.get("delays")), "nearest")


def _grid(stored: Mapping[str, Any]) -> tuple[int, int] | None:
    """A stored kind's grid, or None where it has none (or it does not read as one)."""
    try:
        return parse_resolution(str(stored["grid"])) if stored.get("grid") else None
    except ConfigError:
        return None


def results_grid(results: Mapping[str, Any]) -> tuple[int, int] | None:
    """The SRP grid ``(n_theta, n_phi)`` of a run's observations, or None where no kind is on one."""
    return next((grid for grid in map(_grid, _stored_kinds(results)) if grid is not None), None)


def results_inputs(results: Mapping[str, Any]) -> list[tuple[str, tuple[int, int] | None]]:
    """``(kind, grid)`` for each kind a run's tracker read, the grid where a request names the kind
    with it (``srp:16x32``, a plug-in's map; None for ``srp_max``, which comes with srp, and for
    kinds off the grid). doabench's own kinds are known without the registry; another kind on a
    grid is taken as a requested map."""
    builtin = {kind.name: kind for kind in BUILTIN_KINDS}
    out = []
    for stored in _stored_kinds(results):
        name = str(stored.get("kind"))
        own = builtin.get(name)
        out.append((name, _grid(stored) if own is None or own.requestable else None))
    return out


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
