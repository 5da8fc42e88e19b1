"""Leaderboard inputs: results files and published reference rows, loaded, checked, grouped by
task and ranked (the headline: mean of per-recording RMSAEs for LOCATA, else the pooled RMSAE).
:mod:`doabench.results.leaderboard` renders them as Markdown and CSV."""
from __future__ import annotations

import csv
import hashlib
import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

from doabench.errors import InputError

SCHEMA_PREFIX = "doabench.results/"
SUPPORTED_SCHEMAS = ("doabench.results/1",)
#: the metric rows are ranked by: the paper's tracking metric (Fig. 8, Table II: silent frames included)
RANK_METRIC = "rmsae_all"


@dataclass(frozen=True)
class RunFile:
    """One results JSON: where it is (as shown in tables), its SHA-256 and its content."""

    path: str
    sha256: str
    results: dict[str, Any]

    @property
    def task_id(self) -> str:
        return str(self.results["task"]["id"])

    @property
    def tracker_id(self) -> str:
        """The tracker id, with its options when the run had any (two configurations of one tracker
        are two rows that can be told apart): ``srp-kalman:32x64 (alpha=0.2)``."""
        tracker = self.results["tracker"]
        base = str(tracker.get("id") or tracker.get("name"))
        options = tracker.get("options") or {}
        if not options:
            return base
        shown = {k: (Path(str(v)).name if k == "weights" else v) for k, v in sorted(options.items())}
        return base + " (" + ", ".join(f"{k}={v}" for k, v in shown.items()) + ")"


@dataclass(frozen=True)
class ReferenceRow:
    """A published number (not reproduced by doabench) for one task, method and recording."""

    task_id: str
    recording: str
    method: str
    rmsae_all: float
    source: str
    note: str


@dataclass
class TaskBoard:
    """What one task's table is built from."""

    task_id: str
    runs: list[RunFile] = field(default_factory=list)
    references: list[ReferenceRow] = field(default_factory=list)


# -- reading --------------------------------------------------------------------------------------
def display_path(path: Path) -> str:
    """Path relative to the working directory when below it (tables must not embed a home folder)."""
    try:
        return path.resolve().relative_to(Path.cwd().resolve()).as_posix()
    except ValueError:
        return path.as_posix()


def load_runs(folder: str | Path) -> list[RunFile]:
    """Every ``*.json`` results file in ``folder`` (sorted by name). Other JSON files (no
    ``schema`` key of the results family) are ignored; unreadable ones raise InputError."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"results folder {folder} does not exist")
    runs = []
    for path in sorted(folder.glob("*.json")):
        if path.name.startswith("."):
            continue
        data = path.read_bytes()
        try:
            results = json.loads(data)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise InputError(f"{path} is not valid JSON ({exc}); fix or remove it") from None
        schema = results.get("schema") if isinstance(results, dict) else None
        if not (isinstance(schema, str) and schema.startswith(SCHEMA_PREFIX)):
            continue
        if schema not in SUPPORTED_SCHEMAS:
            raise InputError(f"{path} has results schema {schema!r}; this doabench reads {', '.join(SUPPORTED_SCHEMAS)}")
        for key in ("task", "tracker", "summary", "environment"):
            if not isinstance(results.get(key), dict):
                raise InputError(f"{path} lacks the {key!r} section of a results file")
        runs.append(RunFile(display_path(path), hashlib.sha256(data).hexdigest(), results))
    return runs


def load_references(path: str | Path) -> list[ReferenceRow]:
    """Published rows from a reference CSV (columns ``task``, ``recording``, ``model``, ``input``,
    ``resolution``, ``rmsae_all_deg``, ``status``, ``reference``; the LOCATA Table II layout).
    ``task`` N becomes the task id ``locata-N``; ``all`` rows are kept with task id ``all``."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise InputError(f"reference table {path} cannot be read ({exc.strerror})") from None
    rows = []
    reader = csv.DictReader(io.StringIO(text))
    needed = {"task", "recording", "model", "rmsae_all_deg"}
    if not needed <= set(reader.fieldnames or ()):
        raise InputError(f"reference table {path} needs columns {', '.join(sorted(needed))}")
    for line, row in enumerate(reader, start=2):
        try:
            value = float(row["rmsae_all_deg"])
        except ValueError:
            raise InputError(f"{path} line {line}: rmsae_all_deg {row['rmsae_all_deg']!r} is not a number") from None
        task = row["task"].strip()
        method = row["model"].strip()
        inp, res = row.get("input", "").strip(), row.get("resolution", "").strip()
        details = ", ".join(x for x in (inp, "" if res in inp else res) if x)
        where = ", ".join(f"{k} {row[k].strip()}" for k in ("split", "array", "frames") if row.get(k, "").strip())
        rows.append(ReferenceRow(
            task_id=task if task == "all" else f"locata-{task}",
            recording=row["recording"].strip(),
            method=f"{method} ({details})" if details else method,
            rmsae_all=value,
            source=row.get("reference", "").strip() or path.name,
            note=(row.get("status", "").strip() or "published; not reproduced by doabench")
            + (f" ({where})" if where else ""),
        ))
    return rows


def collect(runs: Iterable[RunFile], references: Iterable[ReferenceRow] = ()) -> dict[str, TaskBoard]:
    """Group runs and reference rows by task id (sorted)."""
    boards: dict[str, TaskBoard] = {}
    for run in runs:
        boards.setdefault(run.task_id, TaskBoard(run.task_id)).runs.append(run)
    for ref in references:
        if ref.task_id != "all":
            boards.setdefault(ref.task_id, TaskBoard(ref.task_id)).references.append(ref)
    for board in boards.values():
        board.runs.sort(key=_run_sort_key)
    return dict(sorted(boards.items()))


# -- ranking ---------------------------------------------------------------------------------------
def recording_mean(results: dict[str, Any]) -> float | None:
    """The mean of the per-recording RMSAEs over all frames (LOCATA's headline, the paper's Table II),
    or None for a task without recordings."""
    values = [float(row["rmsae_all"]) for row in results.get("episodes") or []
              if row.get("recording") is not None and row.get("rmsae_all") is not None]
    return sum(values) / len(values) if values else None


def headline(results: dict[str, Any]) -> float | None:
    """The number a run is ranked by: the mean of per-recording RMSAEs for recording tasks
    (LOCATA), else the RMSAE pooled over every frame."""
    mean = recording_mean(results)
    return mean if mean is not None else results["summary"].get(RANK_METRIC)


def _run_sort_key(run: RunFile) -> tuple:
    value = headline(run.results)
    value = float("inf") if value is None or math.isnan(float(value)) else float(value)
    return (value, run.tracker_id, run.path)
