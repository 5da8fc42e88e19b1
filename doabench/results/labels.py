"""How a run's tracker reads in leaderboards, comparisons and figure legends: its id and, when it
had any, its options (``srp-kalman:32x64 (alpha=0.5)``), and the task options the run used where
they differ from the task's (``srp-max:16x32 [backend=pyroomacoustics]``), so two configurations
never read the same. One rule for every view, so a row of a leaderboard and a line of a figure match."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Iterable, Mapping


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
