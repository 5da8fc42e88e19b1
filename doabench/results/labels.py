"""How a run's tracker reads in leaderboards, comparisons and figure legends: its id and, when it
had any, its options (``srp-kalman:32x64 (alpha=0.5)``; shipped weights by their short name,
``cross3d:16x32 (weights=moving)``, whether or not the run named them), and the task options the run used where
they differ from the task's (``srp-max:16x32 [backend=pyroomacoustics]``), so two configurations
never read the same. One rule for every view, so a row of a leaderboard and a line of a figure match."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Iterable, Mapping

from doabench.results.identity import canonical_id, results_task_options, results_weights_name


def option_text(key: str, value: Any) -> str:
    """``key=value``; a weights file shows as its file name, not the folder it was read from."""
    if key == "weights" and isinstance(value, str) and value != "random":
        value = Path(value).name
    return f"{key}={value if isinstance(value, str) else json.dumps(value, sort_keys=True)}"


def labelled(name: str, options: Mapping[str, Any] | None, extra: Iterable[str] = ()) -> str:
    """``name`` followed by its sorted ``options`` and any ``extra`` ``key=value`` texts in brackets."""
    bits = [option_text(str(k), v) for k, v in sorted((options or {}).items())] + list(extra)
    return f"{name} ({', '.join(bits)})" if bits else name


def configuration_label(name: str, options: Mapping[str, Any] | None, task_options: Mapping[str, Any] | None = None,
                        extra: Iterable[str] = ()) -> str:
    """:func:`labelled`, then the run's task options in square brackets when it had any."""
    text = labelled(name, options, extra)
    if task_options:
        text += " [" + ", ".join(option_text(str(k), v) for k, v in sorted(task_options.items())) + "]"
    return text


def run_label(results: Mapping[str, Any], extra: Iterable[str] = ()) -> str:
    """The label of a results file's configuration: canonical id, options with the shipped
    weights' name (``cross3d:16x32 (weights=paper)`` for a run of the plain weights too), then
    ``extra`` and its task options."""
    tracker = results.get("tracker") or {}
    options = dict(tracker.get("options") or {})
    name = results_weights_name(results)
    if name is not None:
        options["weights"] = name
    return configuration_label(canonical_id(dict(results)), options, results_task_options(results), extra)
