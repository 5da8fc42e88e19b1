"""Leaderboard inputs: results files and published reference rows, loaded, checked, grouped by
task and ranked (the headline: mean of per-recording RMSAEs for LOCATA, else the pooled RMSAE).
:mod:`doabench.reporting.leaderboard` renders them as Markdown and CSV.

Complete runs (every episode of the task) are ranked; partial runs (``--episodes N``,
``--cells``) are ranked apart, among themselves, with their coverage (``36 of 360 episodes``), so
a partial run never moves a complete run's rank. One model is one row per results folder: of
several files of one configuration (task version, canonical tracker id, options, weights, delays)
in one folder only the most complete, then newest, is shown; the others are listed as superseded.
A file of an older schema is read as the current one (:mod:`doabench.results.upgrade`).

Several results folders are read together. One configuration with files in two of them is shown
once per folder, each row labelled by its folder and its episode count (``RunFile.folder``,
``RunFile.in_several_folders``): which of them is the better evidence is for the reader to judge,
not an accident of the order the folders were given in. A JSON file in a folder that is not a
results file this doabench reads (another tool's file, an unknown schema, a section the results
JSON Schema requires missing or of the wrong type) is skipped, and named on standard error with
the reason."""
from __future__ import annotations

import csv
import hashlib
import io
import math
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

from doabench.errors import ConfigError, InputError
from doabench.results.labels import inert_text, inert_texts, run_label
from doabench.results.identity import results_delays
from doabench.results.schema import JsonBoundsError, json_files, read_results, results_problem, summary_problem
from doabench.results.upgrade import UpgradeError

#: the metric rows are ranked by: the paper's tracking metric (Fig. 8, Table II: silent frames included)
RANK_METRIC = "rmsae_all"


@dataclass(frozen=True)
class RunFile:
    """One results JSON: where it is (as shown in tables), its SHA-256 and its content; the results
    folder it was read from (as given, shown in tables), and whether a file of its configuration is
    shown from another folder too (set by :func:`collect`: its rows then name their folders)."""

    path: str
    sha256: str
    results: dict[str, Any]
    folder: str = ""
    in_several_folders: bool = False

    @property
    def task_id(self) -> str:
        return str(self.results["task"]["id"])

    @property
    def complete(self) -> bool:
        """The run scored every episode of its task (only complete runs are ranked)."""
        return is_complete(self.results)

    @property
    def tracker_id(self) -> str:
        """The row's label (:func:`doabench.results.labels.run_label`): the canonical tracker id
        (:func:`canonical_id`), with its options (shipped weights by name) and its task options where
        they differ from the task's, so two configurations are two rows that can be told apart:
        ``srp-kalman:32x64 (alpha=0.2)``, ``srp-max:16x32 [backend=gpurir]``."""
        return run_label(self.results)


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
    """What one task's table is built from: ``runs`` (complete, ranked), ``partial`` (ranked apart,
    among themselves), ``superseded`` (``(file, the row's file)``: another file of the same
    configuration in the same folder)."""

    task_id: str
    runs: list[RunFile] = field(default_factory=list)
    references: list[ReferenceRow] = field(default_factory=list)
    partial: list[RunFile] = field(default_factory=list)
    superseded: list[tuple[RunFile, RunFile]] = field(default_factory=list)


def is_complete(results: dict[str, Any]) -> bool:
    """Every episode of the task was scored."""
    task = results.get("task") or {}
    return task.get("episodes_run") == task.get("episodes_total")


def coverage(results: dict[str, Any]) -> str:
    """``36/360 episodes, 18/18 cells`` (cells for grid tasks whose file records them)."""
    task = results.get("task") or {}
    text = f"{task.get('episodes_run')}/{task.get('episodes_total')} episodes"
    if task.get("cells_total"):
        text += f", {task.get('cells_run')}/{task['cells_total']} cells"
    return text


def episode_count(results: dict[str, Any]) -> str:
    """How many episodes a run holds, as a row is marked: ``360 episodes`` for a complete run,
    ``36 of 360 episodes`` for a partial one."""
    task = results.get("task") or {}
    if is_complete(results):
        return f"{task.get('episodes_run')} episodes"
    return f"{task.get('episodes_run')} of {task.get('episodes_total')} episodes"


def partial_coverage(results: dict[str, Any]) -> str:
    """A partial run's mark: ``36 of 360 episodes, 18 of 18 cells`` (cells where the file records them)."""
    task = results.get("task") or {}
    text = episode_count(results)
    if task.get("cells_total"):
        text += f", {task.get('cells_run')} of {task['cells_total']} cells"
    return text


def configuration_key(run: RunFile) -> tuple:
    """What makes two files one row: task version, canonical tracker id with options and task
    options (its label), weights, delays."""
    r = run.results
    return (r["task"].get("version"), run.tracker_id, r["tracker"].get("weights_hash"), results_delays(r))


def _preference(run: RunFile) -> tuple:
    """Which of one configuration's files is shown: complete first, then most episodes, newest, name."""
    task, env = run.results["task"], run.results.get("environment") or {}
    return (not run.complete, -int(task.get("episodes_run") or 0), _negated(str(env.get("date") or "")), run.path)


def _negated(text: str) -> tuple:
    return tuple(-ord(c) for c in text)


# -- reading --------------------------------------------------------------------------------------
def display_path(path: Path) -> str:
    """Path relative to the working directory when below it (tables must not embed a home folder)."""
    try:
        return path.resolve().relative_to(Path.cwd().resolve()).as_posix()
    except ValueError:
        return path.as_posix()


def warn_skipped(message: str) -> None:
    """Where :func:`load_runs` names a skipped file: standard error."""
    print(f"doabench: warning: {message}", file=sys.stderr)


def load_runs(folders: str | Path | Sequence[str | Path], warn: Callable[[str], None] = warn_skipped) -> list[RunFile]:
    """Every ``*.json`` results file in ``folders`` (one or several; each sorted by name, a folder
    given twice read once), each knowing its folder (``RunFile.folder``). Other JSON files are
    skipped and named through ``warn`` with the reason
    (:func:`doabench.results.schema.results_problem`); a file that is no JSON at all and a missing
    folder raise InputError."""
    unique: dict[Path, Path] = {}
    for folder in [folders] if isinstance(folders, (str, Path)) else folders:
        unique.setdefault(Path(folder).resolve(), Path(folder))
    return [run for folder in unique.values() for run in _load_folder(folder, warn)]


def _load_folder(folder: Path, warn: Callable[[str], None]) -> list[RunFile]:
    """The results files of one folder, sorted by name (see :func:`load_runs`)."""
    if not folder.is_dir():
        raise InputError(f"results folder {folder} does not exist")
    shown_folder = inert_text(display_path(folder))
    runs = []
    for path in json_files(folder):
        try:
            data, results = read_results(path)
        except UpgradeError as exc:  # an older file whose content cannot be read as the current schema
            warn(f"skipped {display_path(path)}: {exc}")
            continue
        except JsonBoundsError as exc:  # a FIFO, a huge or a deeply nested file: no results file, never parsed
            warn(f"skipped {display_path(path)}: {exc.reason}")
            continue
        except OSError as exc:
            raise InputError(f"{path} cannot be read ({exc.strerror or exc})") from None
        except InputError as exc:
            raise InputError(f"{exc}; fix or remove it") from None
        problem = results_problem(results) or summary_problem(results) or _observations_problem(results)
        if problem:
            warn(f"skipped {display_path(path)}: {problem}")
            continue
        # what the views show of a file (its name, its texts) is escaped (doabench.results.labels)
        runs.append(RunFile(inert_text(display_path(path)), hashlib.sha256(data).hexdigest(), inert_texts(results),
                            folder=shown_folder))
    return runs


def _observations_problem(results: dict[str, Any]) -> str | None:
    """Why a file's ``observations`` cannot be read back (a kind not known here), or None."""
    try:
        results_delays(results)
    except ConfigError as exc:
        return f"observations: {exc}"
    return None


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
    """Group runs and reference rows by task id (sorted); per task and results folder one file per
    configuration (:func:`configuration_key`); a configuration shown from several folders has each
    of its rows marked (``in_several_folders``). Complete runs are ranked, partial ones ranked
    apart, each by :func:`headline`."""
    boards: dict[str, TaskBoard] = {}
    by_config: dict[tuple, list[RunFile]] = {}
    for run in runs:
        boards.setdefault(run.task_id, TaskBoard(run.task_id))
        by_config.setdefault((run.task_id, configuration_key(run), run.folder), []).append(run)
    folders: dict[tuple, set[str]] = {}
    for task_id, key, folder in by_config:
        folders.setdefault((task_id, key), set()).add(folder)
    for (task_id, key, _), group in by_config.items():
        shown, *others = sorted(group, key=_preference)
        if len(folders[(task_id, key)]) > 1:  # its rows say which folder and how many episodes each is
            shown = replace(shown, in_several_folders=True)
        board = boards[task_id]
        (board.runs if shown.complete else board.partial).append(shown)
        board.superseded += [(other, shown) for other in others]
    for ref in references:
        if ref.task_id != "all":
            boards.setdefault(ref.task_id, TaskBoard(ref.task_id)).references.append(ref)
    for board in boards.values():
        board.runs.sort(key=_run_sort_key)
        board.partial.sort(key=_run_sort_key)
        board.superseded.sort(key=lambda pair: pair[0].path)
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
