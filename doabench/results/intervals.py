"""The 95 % interval a view prints for one results file: its summary's, or one grid cell's.

A results file's interval is a bootstrap over its own episodes. With fewer than
:data:`doabench.metrics.MIN_INTERVAL_EPISODES` episodes that have scored frames, or with every
resample giving the same value although the episodes differ, that bootstrap says nothing about the
spread, and the file holds ``null`` (:func:`doabench.metrics.bootstrap_ci_from_sums`), which every
view (the leaderboards, ``doabench run``'s summary) prints as :data:`NO_INTERVAL`. Files of the
first results schema were written before that rule; their upgrade applies it
(:func:`drop_undefined_intervals`, :mod:`doabench.results.upgrade`).
"""
from __future__ import annotations

import math
from typing import Any, Mapping

from doabench.metrics import MIN_INTERVAL_EPISODES, defined_interval

#: the per-episode frame count each pooled RMSAE is weighted by (a row's ``n_frames`` or ``n_nonsilent``)
FRAME_COUNTS = {"rmsae_all": "n_frames", "rmsae_nonsilent": "n_nonsilent"}
#: what a view prints in place of an interval the episodes do not give
NO_INTERVAL = "n/a"
#: why a view shows :data:`NO_INTERVAL` (its legend under a table or a summary that shows one)
NO_INTERVAL_NOTE = (f"fewer than {MIN_INTERVAL_EPISODES} episodes with scored frames, or every bootstrap resample "
                    "gave the same value although the episodes differ")


def shown_interval(results: Mapping[str, Any], metric: str, cell: str | None = None) -> tuple[float, float] | None:
    """The 95 % interval of ``metric`` (``rmsae_all`` or ``rmsae_nonsilent``) of a results file,
    of its summary or of grid cell ``cell`` (a cell id of ``results["cells"]``), as ``(low, high)``;
    None where the file holds none (or not two finite numbers)."""
    part = results.get("summary") if cell is None else (results.get("cells") or {}).get(cell)
    stored = part.get(f"{metric}_ci95") if isinstance(part, Mapping) else None
    if not isinstance(stored, (list, tuple)):
        return None
    try:
        low, high = (float(v) for v in stored)
    except (TypeError, ValueError):
        return None
    return (low, high) if math.isfinite(low) and math.isfinite(high) else None


def drop_undefined_intervals(results: dict[str, Any]) -> None:
    """Set every interval of the summary and cells of ``results`` (changed in place) that its
    episodes do not back to None (:func:`doabench.metrics.defined_interval`: the rule a file is
    written by). The episodes of a cell are the rows whose ``task`` is the cell's id; a file whose
    rows do not say so is judged by the cell's ``n_episodes``."""
    rows = [row for row in results.get("episodes") or [] if isinstance(row, Mapping)]
    parts: list[tuple[str | None, Any]] = [(None, results.get("summary"))]
    cells = results.get("cells")
    parts += list(cells.items()) if isinstance(cells, Mapping) else []
    for cell, part in parts:
        if not isinstance(part, dict):
            continue
        own = rows if cell is None else [row for row in rows if row.get("task") == cell]
        for metric in FRAME_COUNTS:
            key = f"{metric}_ci95"
            if part.get(key) is not None and _backed(part, own, metric, cell) is None:
                part[key] = None


def _backed(part: Mapping[str, Any], rows: list[Mapping[str, Any]], metric: str,
            cell: str | None) -> tuple[float, float] | None:
    """The stored interval of ``metric`` where the episodes ``rows`` back it, else None."""
    episodes = _episode_values(rows, metric) if rows or cell is None else None
    if episodes is None:
        # rows that cannot be read: the episode count alone decides (as if each had frames and differed)
        try:
            count = int(part.get("n_episodes", len(rows)) if cell is not None else len(rows))
        except (TypeError, ValueError):
            return None
        episodes = [float(i) for i in range(count)], [1.0] * count
    return defined_interval(*episodes, part.get(f"{metric}_ci95"))


def _episode_values(rows: list[Mapping[str, Any]], metric: str) -> tuple[list[float], list[float]] | None:
    """Each row's ``metric`` and its frame count, or None when some row lacks them."""
    count_key = FRAME_COUNTS.get(metric)
    values, frames = [], []
    for row in rows:
        value, n = row.get(metric), row.get(count_key) if count_key else None
        if isinstance(n, bool) or not isinstance(n, (int, float)) or not (
                value is None or (isinstance(value, (int, float)) and not isinstance(value, bool))):
            return None
        values.append(float("nan") if value is None else float(value))
        frames.append(float(n))
    return values, frames


def interval_text(interval: tuple[float, float] | None) -> str:
    """``[low, high]`` with two decimals, or ``n/a`` (:data:`NO_INTERVAL`) for no interval."""
    return NO_INTERVAL if interval is None else f"[{interval[0]:.2f}, {interval[1]:.2f}]"
