"""Which episodes two results files share: the pairs ``doabench compare`` takes its differences over.

Two runs of one task pair episode by episode: same task, task version and task options, and each
shared episode index has the same seed in both (else the files ran other episodes and are refused
in one line). Two tasks that render the same scenes differently (``sim-walk`` and
``sim-walk-pra``) pair by scene seed instead (``by_seed``). The grid cells of the first run are the
strata of the comparison.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from doabench.errors import InputError
from doabench.results.identity import results_task_options
from doabench.results.labels import inert_texts, run_label
from doabench.results.schema import load_results, summary_problem


@dataclass
class Run:
    """A results file as compared: its path, content and the label tables show."""

    path: Path
    results: dict[str, Any]
    label: str = ""

    @property
    def rows(self) -> list[dict[str, Any]]:
        return list(self.results.get("episodes") or [])

    @property
    def task(self) -> dict[str, Any]:
        return self.results.get("task") or {}


def load_run(path: str | Path) -> Run:
    """A results JSON written by ``doabench run``; InputError (one line) otherwise."""
    path = Path(path)
    data = inert_texts(load_results(path))  # its texts are shown, never interpreted (doabench.results.labels)
    if not data.get("episodes"):
        raise InputError(f"{path} has no per-episode rows to pair")
    problem = summary_problem(data)
    if problem:
        raise InputError(f"{path}: {problem}")
    return Run(path, data, run_label(data))


def distinct_labels(runs: Sequence[Run]) -> None:
    """Runs whose labels coincide (one tracker, two weights or two folders) get the file name too."""
    for run in runs:
        if sum(r.label == run.label for r in runs) > 1:
            run.label = f"{run.label} [{run.path.name}]"
    for i, run in enumerate(runs):
        if sum(r.label == run.label for r in runs) > 1:
            run.label = f"{run.label} #{i + 1}"


@dataclass
class Pairing:
    """The episodes two runs share, in episode order: ``rows_a[i]`` and ``rows_b[i]`` are the same
    episode (same index and seed); ``frames_a``/``frames_b`` their per-frame estimates or None."""

    a: Run
    b: Run
    rows_a: list[dict[str, Any]]
    rows_b: list[dict[str, Any]]
    frames_a: list[dict[str, Any]] | None
    frames_b: list[dict[str, Any]] | None
    cells: dict[str, np.ndarray] = field(default_factory=dict)  # cell id -> positions in the rows

    @property
    def n(self) -> int:
        return len(self.rows_a)


def frames_by_episode(run: Run) -> dict[int, dict[str, Any]] | None:
    """The run's per-frame estimates by episode index (None without them), each carrying whether
    the run folds directions onto a plane (a planar array), as its scores did."""
    frames = run.results.get("frames")
    if not frames or len(frames) != len(run.rows) or any(f is None for f in frames):
        return None
    planar = bool((run.results.get("scoring") or {}).get("planar_fold"))
    return {int(row["episode"]): {**f, "planar": planar} for row, f in zip(run.rows, frames)}


def pair(a: Run, b: Run, by_seed: bool = False) -> Pairing:
    """The episodes ``a`` and ``b`` share; InputError saying why when they cannot be paired.

    ``by_seed``: pair the episodes of two *tasks* that draw the same scenes (same scene seeds) and
    render them differently, e.g. ``sim-walk`` and ``sim-walk-pra`` (builtin and pyroomacoustics):
    episodes are matched by seed, the cells are ``a``'s."""
    ta, tb = a.task, b.task
    if by_seed:
        return _pair_by_seed(a, b)
    if ta.get("id") != tb.get("id"):
        raise InputError(f"{a.path} is a run of task {ta.get('id')} and {b.path} of task {tb.get('id')}: "
                         "only runs of the same task share episodes")
    if ta.get("version") != tb.get("version"):
        raise InputError(f"{a.path} ran {ta.get('id')} v{ta.get('version')} and {b.path} v{tb.get('version')}: "
                         "different task versions have different episodes")
    over_a, over_b = results_task_options(a.results), results_task_options(b.results)
    if over_a != over_b:  # another simulator, scene overrides, LOCATA split or VAD
        raise InputError(f"{a.path} and {b.path} ran {ta.get('id')} with different task options "
                         f"({json.dumps(over_a, sort_keys=True)} and {json.dumps(over_b, sort_keys=True)}): "
                         "not the same episodes or scoring (--by-seed pairs two renderings of the same scenes)")
    by_b = {int(r["episode"]): r for r in b.rows}
    shared_a, shared_b = [], []
    for row in sorted(a.rows, key=lambda r: int(r["episode"])):
        other = by_b.get(int(row["episode"]))
        if other is None:
            continue
        if row.get("seed") != other.get("seed"):
            raise InputError(f"episode {row['episode']} has seed {row.get('seed')} in {a.path} and "
                             f"{other.get('seed')} in {b.path}: not the same episodes (another base seed or "
                             "simulator?)")
        shared_a.append(row)
        shared_b.append(other)
    if not shared_a:
        raise InputError(f"{a.path} and {b.path} have no episode in common (episodes "
                         f"{_span(a.rows)} and {_span(b.rows)})")
    # rows without a cell of their own (a task that is no grid) are in no cell
    return _pairing(a, b, shared_a, shared_b, keep_task_cell=False)


def _pair_by_seed(a: Run, b: Run) -> Pairing:
    by_b = {r.get("seed"): r for r in b.rows if r.get("seed") is not None}
    shared_a = [r for r in sorted(a.rows, key=lambda r: int(r["episode"])) if r.get("seed") in by_b]
    if not shared_a:
        raise InputError(f"{a.path} ({a.task.get('id')}) and {b.path} ({b.task.get('id')}) share no scene seed: "
                         "they are not renderings of the same scenes")
    return _pairing(a, b, shared_a, [by_b[r["seed"]] for r in shared_a], keep_task_cell=True)


def _pairing(a: Run, b: Run, shared_a: list[dict[str, Any]], shared_b: list[dict[str, Any]],
             keep_task_cell: bool) -> Pairing:
    """The pairing of the shared rows, with their frame records and ``a``'s grid cells (none
    unless there are two or more); a row without a cell of its own counts in the cell named by the
    task id only when ``keep_task_cell``."""
    fa, fb = frames_by_episode(a), frames_by_episode(b)
    frames_a = [fa[int(r["episode"])] for r in shared_a] if fa is not None else None
    frames_b = [fb[int(r["episode"])] for r in shared_b] if fb is not None else None
    task_id = str(a.task.get("id"))
    cells: dict[str, list[int]] = {}
    for i, row in enumerate(shared_a):
        cell = str(row.get("task") or a.task.get("id"))
        if keep_task_cell or cell != task_id:
            cells.setdefault(cell, []).append(i)
    return Pairing(a, b, shared_a, shared_b, frames_a, frames_b,
                   {k: np.asarray(v) for k, v in cells.items()} if len(cells) > 1 else {})


def _span(rows: Sequence[dict[str, Any]]) -> str:
    idx = sorted(int(r["episode"]) for r in rows)
    return f"{idx[0]}-{idx[-1]}" if idx else "none"
