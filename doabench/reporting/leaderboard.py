"""Leaderboards from committed results files: one Markdown table and one CSV per task, plus a summary.

Loading and ranking are :mod:`doabench.results.ranking`; this module renders the boards.

Every number in a generated table comes from a results JSON written by ``doabench run`` (or from a
reference CSV of published numbers, which is marked as such). Each row names the file it came from
(with its SHA-256) and the run's provenance: tracker id and version, weights hash, git commit,
seeds, hardware and date, and the ``doabench run`` command that reproduces it.

Output is deterministic: rows and files are sorted, numbers have fixed formats and nothing but the
results' own dates appears, so regenerating from the same inputs gives byte-identical files.
"""
from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path
from typing import Any, Sequence

from doabench.envs.sources import recorded_task_kind
from doabench.reporting.distribution import IN, training_distribution
from doabench.results.ranking import (ReferenceRow, RunFile, TaskBoard, collect, coverage, display_path,
                                      episode_count, load_references, load_runs, partial_coverage, recording_mean)
from doabench.files import file_stem
from doabench.geometry import resolution_text
from doabench.results.identity import (canonical_id, results_delays, results_grid, results_inputs, results_kinds,
                                       results_task_options, results_weights_name)
from doabench.results.intervals import NO_INTERVAL, NO_INTERVAL_NOTE, shown_interval
from doabench.results.labels import csv_cell
from doabench.trackers.registry import TRACKERS

PUBLISHED = "published"
REPRODUCED = "doabench run"


# -- formatting helpers -----------------------------------------------------------------------------
def _num(x: Any, digits: int = 2) -> str:
    if x is None:
        return "—"
    x = float(x)
    return "—" if math.isnan(x) else f"{x:.{digits}f}"


#: a value without an interval of its own (:func:`doabench.results.intervals.shown_interval`)
NO_INTERVAL_CELL = f"[{NO_INTERVAL}]"


def _with_ci(value: Any, interval: tuple[float, float] | None) -> str:
    """``12.34 [10.00, 15.00]``; ``12.34 [n/a]`` where the file's episodes give no interval."""
    text = _num(value)
    if text == "—":
        return text
    return f"{text} [{interval[0]:.2f}, {interval[1]:.2f}]" if interval else f"{text} {NO_INTERVAL_CELL}"


def _file_ci(results: dict[str, Any], metric: str, cell: str | None = None) -> str:
    """A results file's value of ``metric`` (of its summary, or of grid cell ``cell``) with its interval."""
    part = results["summary"] if cell is None else (results.get("cells") or {}).get(cell) or {}
    return _with_ci(part.get(metric), shown_interval(results, metric, cell))


def _no_interval_legend(rows: Sequence[Sequence[str]]) -> list[str]:
    """The legend of ``[n/a]`` under a table that shows one."""
    if not any(NO_INTERVAL_CELL in str(cell) for row in rows for cell in row):
        return []
    return ["", f"**{NO_INTERVAL_CELL}**: no 95% interval ({NO_INTERVAL_NOTE})."]


def tracker_cell(run: RunFile) -> str:
    """A row's tracker as a table shows it: its label, and where its configuration is shown from
    several results folders, the folder and the episodes of this row
    (``srp-max:16x32`` (`runs/mine`, 36 of 360 episodes))."""
    text = f"`{run.tracker_id}`"
    return text + (f" (`{run.folder}`, {episode_count(run.results)})" if run.in_several_folders else "")


def _cell(text: Any) -> str:
    """Markdown table cell text: pipes escaped, no line breaks."""
    return str(text).replace("|", "\\|").replace("\n", " ")


def _csv_num(x: Any) -> str:
    if x is None:
        return ""
    x = float(x)
    return "" if math.isnan(x) else f"{x:.4f}"


def safe_name(task_id: str) -> str:
    """File name stem of a task's table: ``sim-grid``, ``file_data.h5`` for ``file:data.h5``."""
    return file_stem(task_id, "task")


# -- provenance ---------------------------------------------------------------------------------------
def kind_reproduce_flags(task: dict[str, Any]) -> list[str]:
    """The run-time flags of the task's kind that re-create a run (corpus roots as placeholders),
    as the kind's options declare them (``Options.reproduce_flags(task["source"])``); none for a
    kind that declares none, or that is neither doabench's own nor registered already (a kind
    named by a results file loads no plug-in: :func:`doabench.envs.sources.recorded_task_kind`)."""
    options = getattr(recorded_task_kind(str(task.get("kind"))), "Options", None)
    flags = getattr(options, "reproduce_flags", None)
    return list(flags(task.get("source") or {})) if callable(flags) else []


def reproduce_command(results: dict[str, Any]) -> str:
    """The ``doabench run`` command line that re-creates a results file (corpus paths as placeholders)."""
    task = results["task"]
    tracker = results["tracker"]
    parts = ["doabench run", f"--tracker {typeable_id(results)}", f"--task {task['id']}"]
    options = dict(tracker.get("options") or {})
    named = results_weights_name(results)
    if named is not None:  # by name, also for the plain weights: the default may have changed since
        options["weights"] = named
    for key, value in sorted(options.items()):
        parts.append(f"--tracker-opt {key}={value}")
    selection = task.get("selection") or {}
    if selection.get("cells"):
        parts.append(f"--cells {','.join(selection['cells'])}")
    if task.get("episodes_run") is not None and task.get("episodes_run") != task.get("episodes_total") and (
            selection.get("rule") != "cells"):
        parts.append(f"--episodes {selection.get('episodes') or task['episodes_run']}")
    delays = results_delays(results)
    if delays != "nearest":
        parts.append(f"--delays {delays}")
    parts += kind_reproduce_flags(task)
    device = (results.get("environment") or {}).get("device")
    if device not in (None, "cpu"):
        parts.append(f"--device {device}")
    scene = results_task_options(results).get("scene_overrides")
    if scene:  # no flag: the Python API's option
        parts.append(f"(Python: doabench.run(..., scene_overrides={json.dumps(scene, sort_keys=True)}))")
    return " ".join(parts)


def typeable_id(results: dict[str, Any]) -> str:
    """The tracker id to type again: the canonical id where a tracker of that name is registered
    here (declared or registered: nothing is loaded), else the text the run was started with
    (``given_id``: a plug-in's ``package.module:Class``)."""
    canonical = canonical_id(results)
    given = (results.get("tracker") or {}).get("given_id")
    if given and canonical.split(":", 1)[0] not in TRACKERS.names():
        return str(given)
    return canonical


def provenance_line(label: str, run: RunFile) -> str:
    """One Markdown list item naming everything a row's numbers depend on."""
    r = run.results
    env = r["environment"]
    git = env.get("git") or {}
    commit = git.get("commit")
    commit_text = "unknown commit" if not commit else f"commit `{commit[:12]}`" + (
        " with uncommitted changes in the working tree" if git.get("dirty") else "")
    tracker = r["tracker"]
    weights = tracker.get("weights_hash")
    task = r["task"]
    scene = (task.get("source") or {}).get("scene_overrides")
    bits = [
        f"`{run.path}` (sha256 `{run.sha256[:16]}`)",
        f"tracker `{run.tracker_id}` version {tracker.get('version', '?')}, "
        + (f"weights sha256 `{weights[:16]}`" if weights else
           "UNTRAINED (random weights)" if _untrained(r) else "no weights"),
        f"task `{task['id']}` v{task.get('version', '?')}, base seed {task.get('base_seed')} "
        f"(per-episode seeds in the file), {coverage(r) if run.complete else partial_coverage(r)}"
        + _selection_text(task),
        commit_text,
        f"doabench {env.get('doabench', '?')}, Python {env.get('python', '?')}, torch {env.get('torch', '?')}, "
        f"numpy {env.get('numpy', '?')}",
        f"{env.get('cpu', '?')} ×{env.get('cpu_count', '?')}, device {env.get('device', '?')}"
        + (f" ({env['gpu']})" if env.get("gpu") else ""),
        f"date {env.get('date', '?')}",
    ]
    if r.get("wall_time_s") is not None:
        bits.append(f"wall time {float(r['wall_time_s']) / 60:.1f} min")
    if scene:
        bits.append(f"scene overrides {json.dumps(scene, sort_keys=True)}")
    return f"- **{label}**: " + "; ".join(bits) + f". Reproduce: `{reproduce_command(r)}`"


# -- training distribution of learned trackers (doabench.reporting.distribution) ---------------------------
IN_MARK, OUT_MARK = "in-distribution", "zero-shot"


def _distribution_mark(results: dict[str, Any]) -> str:
    verdict = training_distribution(results)
    return "" if verdict is None else f" ({IN_MARK if verdict.status == IN else OUT_MARK})"


def _distribution_csv(results: dict[str, Any]) -> str:
    verdict = training_distribution(results)
    return "" if verdict is None else f"{verdict.status} ({verdict.training})" + (
        f": {verdict.why}" if verdict.why else "")


def _distribution_notes(board: TaskBoard) -> list[str]:
    """The legend of the marks: which training task each learned tracker's row is measured against."""
    found = {run.tracker_id: training_distribution(run.results) for run in board.runs}
    verdicts = {k: v for k, v in found.items() if v is not None}
    if not verdicts:
        return []
    lines = ["", f"*{IN_MARK}*: a learned tracker trained on this task's simulator, array and scene family, so its "
                 f"score measures fit to its training distribution rather than generalisation; *{OUT_MARK}*: the task "
                 "lies outside it. Training tasks: "
             + "; ".join(f"`{k}` {v.training}" + (f" ({v.why})" if v.why else "") for k, v in sorted(verdicts.items()))
             + "."]
    return lines


# -- per-task tables ----------------------------------------------------------------------------------
MAIN_COLUMNS = ("rank", "tracker", "causal", "params", "input", "episodes", "RMSAE all frames [95% CI]",
                "RMSAE non-silent [95% CI]", "MAE", "median", "≤10°", "azimuth MAE", "run")


def _recordings(board: TaskBoard) -> list[str]:
    """Recording labels (LOCATA-style tasks: one column per recording), sorted numerically."""
    labels = set()
    for run in board.runs:
        for row in run.results.get("episodes") or []:
            if row.get("recording") is not None:
                labels.add(str(row["recording"]))
    for ref in board.references:
        if ref.recording != "average":
            labels.add(ref.recording)
    return sorted(labels, key=lambda s: (0, int(s)) if s.isdigit() else (1, s))


def _per_recording(run: RunFile) -> dict[str, float]:
    return {str(row["recording"]): row.get("rmsae_all") for row in run.results.get("episodes") or []
            if row.get("recording") is not None}


def _resolution_text(results: dict[str, Any]) -> str:
    """The SRP grid of a run's observations (``16x32``), empty where they have none."""
    grid = results_grid(results)
    return resolution_text(grid) if grid else ""


def _input_text(results: dict[str, Any]) -> str:
    """The kinds a run's tracker read, each kind on the SRP grid that a request names with its grid
    (``srp``, a plug-in map; not ``srp_max``, which comes with srp) followed by the grid:
    ``srp 16x32, srp_max``."""
    parts = [f"{name} {resolution_text(grid)}" if grid else name for name, grid in results_inputs(results)]
    return ", ".join(parts) or "—"


def _episodes_text(task: dict[str, Any]) -> str:
    return f"{task.get('episodes_run')}/{task.get('episodes_total')}"


def _selection_text(task: dict[str, Any]) -> str:
    """How a partial run chose its episodes (empty for a complete run)."""
    if task.get("episodes_run") == task.get("episodes_total"):
        return ""
    selection = task.get("selection") or {}
    rule = selection.get("rule")
    cells = selection.get("cells")
    where = f"cells {', '.join(cells)}" if cells else "the cells"
    if rule == "stratified":
        return f" (`--episodes {selection.get('episodes')}` spread over {where})"
    if rule == "cells":
        return f" (every episode of {where})"
    if rule == "indices":
        return " (chosen episodes)"
    return f" (the first {task.get('episodes_run')})"


def has_lag(runs: Sequence[RunFile]) -> bool:
    """Whether the boards show a lag column: some run's summary has the lag metric (``lag_s``)."""
    return any("lag_s" in (run.results.get("summary") or {}) for run in runs)


def _lag(summary: dict[str, Any]) -> str:
    """The lag in seconds; ``-`` where the run has no defined lag (``null``), ``—`` without the metric."""
    if "lag_s" not in summary:
        return "—"
    return "-" if summary["lag_s"] is None else f"{float(summary['lag_s']):.2f}"


def _lag_notes(runs: Sequence[RunFile]) -> list[str]:
    """What the lag column means, and why a ``-`` has no defined lag (the runs' own notes)."""
    notes = sorted({str(s.get("lag_note")).removesuffix(": no defined lag")
                    for s in (r.results.get("summary") or {} for r in runs)
                    if "lag_s" in s and s.get("lag_s") is None and s.get("lag_note")})
    text = ("**lag [s]**: the delay of the true direction that best fits the estimates (0 to 2 s; "
            "docs/concepts.md)")
    if notes:
        text += "; **-**: no defined lag (" + "; ".join(notes) + ")"
    return ["", text + "."]


def _untrained(results: dict[str, Any]) -> bool:
    """A learned tracker run with random weights on purpose (``weights=random``)."""
    tracker = results.get("tracker") or {}
    return bool(tracker.get("untrained")) or tracker.get("trained") is False


RECORDING_COLUMNS = MAIN_COLUMNS[:6] + ("RMSAE all, mean of recordings", "RMSAE all pooled [95% CI]") + MAIN_COLUMNS[7:]


def _columns(by_recording: bool, with_lag: bool) -> tuple[str, ...]:
    columns = RECORDING_COLUMNS if by_recording else MAIN_COLUMNS
    return columns[:-1] + ("lag [s]",) + columns[-1:] if with_lag else columns


def _main_row(rank: int, run: RunFile, label: str, by_recording: bool = False, with_lag: bool = False) -> list[str]:
    r = run.results
    s = r["summary"]
    pooled = s.get("pooled") or {}
    within = pooled.get("within_10")
    row = [
        str(rank), tracker_cell(run) + (" **(untrained)**" if _untrained(r) else "") + _distribution_mark(r),
        "yes" if r.get("causal") else "no (offline)",
        f"{int(r['tracker'].get('parameters') or 0):,}", _input_text(r), _episodes_text(r["task"]),
        *([_num(recording_mean(r))] if by_recording else []),
        _file_ci(r, "rmsae_all"), _file_ci(r, "rmsae_nonsilent"),
        _num(pooled.get("mae")), _num(pooled.get("median")),
        "—" if within is None else f"{100 * float(within):.0f}%", _num(pooled.get("azimuth_mae")), label,
    ]
    return row[:-1] + [_lag(s)] + row[-1:] if with_lag else row


PARTIAL_COLUMNS = ("rank", "tracker", "covers", "RMSAE all frames [95% CI]", "RMSAE non-silent [95% CI]", "run")
PARTIAL_HEADING = "## Partial runs (ranked apart from complete runs)"


def partial_section(board: TaskBoard, labels: dict[str, str], with_lag: bool) -> list[str]:
    """Partial runs (``--episodes N``, ``--cells``), each marked ``n of N episodes``, ranked among
    themselves in a table of their own: a complete run's rank never depends on them."""
    if not board.partial:
        return []
    lines = ["", PARTIAL_HEADING, "",
             "Runs of some of the task's episodes (`--episodes N`, `--cells`): their numbers hold for the episodes "
             "they cover, so they are ranked here, among themselves (by the same measure as the complete runs), "
             "and never against complete runs; two partial runs over different episodes compare only roughly. "
             "RMSAE in degrees pooled over those episodes, with the 95% bootstrap interval over them.", ""]
    header = PARTIAL_COLUMNS[:-1] + (("lag [s]",) if with_lag else ()) + PARTIAL_COLUMNS[-1:]
    rows = []
    for rank, run in enumerate(board.partial, start=1):
        r = run.results
        s = r["summary"]
        rows.append([str(rank), tracker_cell(run) + (" **(untrained)**" if _untrained(r) else ""),
                     partial_coverage(r) + _selection_text(r["task"]),
                     _file_ci(r, "rmsae_all"), _file_ci(r, "rmsae_nonsilent")]
                    + ([_lag(s)] if with_lag else []) + [labels[run.path]])
    lines += _table(header, rows)
    lines += _no_interval_legend(rows)
    return lines + (_lag_notes(board.partial) if with_lag and not board.runs else [])


def superseded_section(board: TaskBoard, labels: dict[str, str]) -> list[str]:
    """Files not shown because another file of the same configuration is (one model, one row)."""
    if not board.superseded:
        return []
    lines = ["", "## Superseded files", "",
             "Same tracker (aliases resolved: `cross3d` is `cross3d:16x32`), options, weights and task version as "
             "a row above; the most complete, then newest, file is shown.", ""]
    return lines + [f"- `{old.path}` (`{_given_id(old.results)}`, {coverage(old.results)}): "
                    f"see {labels[shown.path]}" for old, shown in board.superseded]


def _given_id(results: dict[str, Any]) -> str:
    """The tracker id as the run was given it (an alias, ``cross3d``), else its canonical id."""
    tracker = results.get("tracker") or {}
    return str(tracker.get("given_id") or tracker.get("id"))


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    out = ["| " + " | ".join(_cell(h) for h in header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows]
    return out


def _grid_axes(runs: Sequence[RunFile]) -> tuple[list[float], list[float]]:
    t60s, snrs = set(), set()
    for run in runs:
        for cell in (run.results.get("cells") or {}).values():
            t60s.add(float(cell["t60"]))
            snrs.add(float(cell["snr"]))
    return sorted(t60s), sorted(snrs)


def _cell_lookup(run: RunFile) -> dict[tuple[float, float], dict[str, Any]]:
    return {(float(c["t60"]), float(c["snr"])): c for c in (run.results.get("cells") or {}).values()}


def _cell_ids(run: RunFile) -> dict[tuple[float, float], str]:
    """Each cell's id (the key of ``cells``, the ``task`` of its episode rows) by ``(t60, snr)``."""
    return {(float(c["t60"]), float(c["snr"])): str(cell) for cell, c in (run.results.get("cells") or {}).items()}


def _g(x: float) -> str:
    return f"{x:g}"


def grid_section(board: TaskBoard, labels: dict[str, str]) -> list[str]:
    """Per tracker, RMSAE per T60 × SNR cell (all frames and non-silent frames, with 95% CIs)."""
    runs = [r for r in board.runs + board.partial if r.results.get("cells")]
    if not runs:
        return []
    t60s, snrs = _grid_axes(runs)
    lines = ["", "## Per cell: T60 × SNR", "",
             "RMSAE in degrees per grid cell with the 95% bootstrap interval over the cell's episodes. "
             "*All* includes silent frames (paper Fig. 8), *non-silent* excludes them (paper Fig. 6)."]
    legend_rows: list[list[str]] = []
    for run in runs:
        cells = _cell_lookup(run)
        ids = _cell_ids(run)
        header = ["T60 [s]"] + [f"SNR {_g(s)} dB, {m}" for s in snrs for m in ("all", "non-silent")]
        rows = []
        for t in t60s:
            row = [_g(t)]
            for s in snrs:
                c = cells.get((t, s))
                if c is None:
                    row += ["—", "—"]
                else:
                    row += [_file_ci(run.results, "rmsae_all", ids[(t, s)]),
                            _file_ci(run.results, "rmsae_nonsilent", ids[(t, s)])]
            rows.append(row)
        n = sorted({int(c.get("n_episodes", 0)) for c in cells.values()})
        lines += ["", f"### {tracker_cell(run)} ({labels[run.path]})", "",
                  f"Episodes per cell: {', '.join(map(str, n))}.", ""]
        lines += _table(header, rows)
        legend_rows += rows
    return lines + _no_interval_legend(legend_rows)


def reference_section(board: TaskBoard, recordings: list[str]) -> list[str]:
    """Published rows: per recording and the published average, clearly marked as not reproduced."""
    if not board.references:
        return []
    methods: dict[str, dict[str, float]] = {}
    for ref in board.references:
        methods.setdefault(ref.method, {})[ref.recording] = ref.rmsae_all
    header = ["method"] + [f"recording {r}" for r in recordings] + ["average (published)", "status"]
    rows = []
    for method, values in sorted(methods.items(), key=lambda kv: (kv[1].get("average", math.inf), kv[0])):
        rows.append([method] + [_num(values.get(r)) for r in recordings] + [_num(values.get("average")),
                                                                              "published, not reproduced"])
    sources = sorted({ref.source for ref in board.references})
    notes = sorted({ref.note for ref in board.references})
    lines = ["", "## Published reference rows (not reproduced)", "",
             "Copied from the literature for comparison; no doabench run produced these numbers. "
             "RMSAE in degrees, all frames (silent frames included). Source: " + "; ".join(sources) + ".",
             "Status in the reference file: " + "; ".join(notes) + ".", ""]
    return lines + _table(header, rows)


def _locata_rows(runs: Sequence[RunFile], labels: dict[str, str]) -> list[list[str]]:
    """Per run with a ``locata`` results block: the challenge's headline measures (both modes) and
    SRP-DNN's protocol."""
    rows = []
    for run in runs:
        block = run.results.get("locata")
        if not block:
            continue
        off, cor, srp = block.get("official") or {}, block.get("corrected") or {}, block.get("srp_dnn") or {}
        accuracy = srp.get("accuracy")
        rows.append([tracker_cell(run), _num(off.get("az_error_ungated_deg")), _num(cor.get("az_error_ungated_deg")),
                     _num(cor.get("pd"), 3), _num(cor.get("latency_s")), _num(off.get("far")),
                     _num((off.get("ospa_deg") or {}).get("1")),
                     "—" if accuracy is None else f"{100 * float(accuracy):.1f}%", _num(srp.get("az_mae_deg")),
                     labels[run.path]])
    return rows


LOCATA_COLUMNS = ("tracker", "azimuth error, official [°]", "azimuth error, corrected [°]", "Pd", "latency [s]",
                  "FAR [1/s]", "OSPA p=1 [°]", "SRP-DNN accuracy", "SRP-DNN azimuth MAE [°]", "run")


def locata_section(board: TaskBoard, labels: dict[str, str]) -> list[str]:
    """The LOCATA challenge's measures of the runs that carry them (docs/locata.md)."""
    rows = _locata_rows(board.runs, labels)
    if not rows:
        return []
    return ["", "### LOCATA challenge measures", "",
            "On every required time stamp (each takes the latest estimate), from the results' `locata` block: the "
            "azimuth error ungated (the challenge's headline) as released (official) and as the paper defines it "
            "(corrected), Pd and track latency (corrected), FAR and OSPA (p = 1, cut-off 30°); SRP-DNN's protocol "
            "(stamps within 30°, MAE over them). Definitions: docs/locata.md.", ""] + _table(LOCATA_COLUMNS, rows)


def task_markdown(board: TaskBoard, command: str) -> str:
    """The Markdown page of one task."""
    labels = {run.path: f"R{i}" for i, run in enumerate(board.runs, start=1)}
    labels.update({run.path: f"P{i}" for i, run in enumerate(board.partial, start=1)})
    recordings = _recordings(board)
    with_lag = has_lag(board.runs + board.partial)
    lines = [f"# Leaderboard: `{board.task_id}`", "",
             "<!-- generated by `doabench leaderboard`; do not edit by hand -->", "",
             f"Regenerate with `{command}`.", ""]
    versions = sorted({str(r.results["task"].get("version")) for r in board.runs + board.partial})
    if len(versions) > 1:
        lines += [f"**Warning**: results of several task versions ({', '.join(versions)}) are mixed here; "
                  "numbers from different versions are not comparable.", ""]
    if board.runs:
        by_recording = bool(recordings) and all(recording_mean(r.results) is not None for r in board.runs)
        if by_recording:
            lines += ["Ranked by the mean of the per-recording RMSAEs over all frames (degrees; the paper's "
                      "Table II; ties by tracker id); the RMSAE pooled over every frame of every recording is "
                      "the second column, with its 95% bootstrap interval over recordings (1000 resamples). "
                      "MAE, median, ≤10° and azimuth MAE are pooled over non-silent frames. Frames whose truth "
                      "is invalid (valid_flag = 0) are not scored. Definitions: docs/concepts.md.", ""]
        else:
            lines += ["Ranked by RMSAE over all frames (degrees, pooled over every frame of every episode; "
                      "ties by tracker id). Brackets: 95% bootstrap interval over episodes (1000 resamples). "
                      "MAE, median, ≤10° and azimuth MAE are over non-silent frames. Definitions: docs/concepts.md.", ""]
        rows = [_main_row(i, run, labels[run.path], by_recording, with_lag) for i, run in enumerate(board.runs, start=1)]
        lines += _table(_columns(by_recording, with_lag), rows)
        lines += _no_interval_legend(rows)
        if with_lag:
            lines += _lag_notes(board.runs + board.partial)
        lines += _distribution_notes(board)
        if any(_untrained(r.results) for r in board.runs):
            lines += ["", "**(untrained)**: a learned tracker run with randomly initialised weights "
                          "(`--tracker-opt weights=random`); a reference point, not a trained model."]
        if recordings:
            lines += ["", "### Per recording (RMSAE all frames)", ""]
            header = ["tracker"] + [f"recording {r}" for r in recordings] + ["mean of recordings", "run"]
            rec_rows = []
            for run in board.runs:
                per = _per_recording(run)
                vals = [per.get(r) for r in recordings]
                present = [float(v) for v in vals if v is not None]
                mean = sum(present) / len(present) if present else None
                rec_rows.append([tracker_cell(run)] + [_num(v) for v in vals] + [_num(mean), labels[run.path]])
            lines += _table(header, rec_rows)
        lines += locata_section(board, labels)
    elif board.partial:
        lines += ["No complete run of this task yet; partial runs below.", ""]
    else:
        lines += ["No doabench results for this task yet: run `doabench run --tracker ... --task "
                  f"{board.task_id} --out results/` and regenerate.", ""]
    lines += partial_section(board, labels, with_lag)
    lines += grid_section(board, labels)
    lines += reference_section(board, recordings)
    if board.runs or board.partial:
        lines += ["", "## Runs", "",
                  "Where each row's numbers come from. Per-episode rows and per-frame estimates are in the "
                  "results file; its CSV twin has the per-episode metrics.", ""]
        lines += [provenance_line(labels[run.path], run) for run in board.runs + board.partial]
    lines += superseded_section(board, labels)
    return "\n".join(lines) + "\n"


CSV_COLUMNS = (
    "status", "rank", "task", "task_version", "tracker", "tracker_name", "tracker_version", "causal", "parameters",
    "features", "resolution", "episodes_run", "episodes_total", "rmsae_all", "rmsae_all_ci95_low",
    "rmsae_all_ci95_high", "rmsae_nonsilent", "rmsae_nonsilent_ci95_low", "rmsae_nonsilent_ci95_high", "mae",
    "median", "p90", "within_5", "within_10", "within_20", "within_30", "azimuth_mae", "lag_s", "recordings",
    "results_file", "results_sha256", "git_commit", "git_dirty", "weights_hash", "base_seed", "cpu", "cpu_count",
    "device", "torch", "doabench", "date", "command", "reference", "training_distribution", "cells_run",
    "cells_total",
)
PARTIAL = "partial run (ranked apart)"


def _csv_text(rows: list[dict[str, Any]], columns: Sequence[str]) -> str:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(columns), lineterminator="\n")
    writer.writeheader()
    writer.writerows({k: csv_cell(v) for k, v in row.items()} for row in rows)  # no formula cells
    return buf.getvalue()


def task_csv(board: TaskBoard) -> str:
    """One row per run (complete runs ranked 1, 2 ...; partial runs ranked apart, P1, P2 ...) and per
    published method; per-recording values as ``rec=value;...``."""
    rows = []
    # partial runs are ranked apart: P1, P2 ... (the page's labels), never numbers among complete runs
    ranked: list[tuple[int | str, RunFile]] = [(rank, run) for rank, run in enumerate(board.runs, start=1)]
    ranked += [(f"P{rank}", run) for rank, run in enumerate(board.partial, start=1)]
    for rank, run in ranked:
        r = run.results
        s, env, task, tr = r["summary"], r["environment"], r["task"], r["tracker"]
        pooled = s.get("pooled") or {}
        all_ci = shown_interval(r, "rmsae_all") or (None, None)
        ns_ci = shown_interval(r, "rmsae_nonsilent") or (None, None)
        per = _per_recording(run)
        rows.append({
            "status": REPRODUCED if run.complete else PARTIAL, "rank": rank,
            "task": task["id"], "task_version": task.get("version"),
            "tracker": run.tracker_id, "tracker_name": tr.get("name"), "tracker_version": tr.get("version"),
            "causal": str(bool(r.get("causal"))).lower(), "parameters": tr.get("parameters"),
            "features": " ".join(results_kinds(r)),
            "resolution": _resolution_text(r),
            "episodes_run": task.get("episodes_run"), "episodes_total": task.get("episodes_total"),
            "rmsae_all": _csv_num(s.get("rmsae_all")), "rmsae_all_ci95_low": _csv_num(all_ci[0]),
            "rmsae_all_ci95_high": _csv_num(all_ci[1]), "rmsae_nonsilent": _csv_num(s.get("rmsae_nonsilent")),
            "rmsae_nonsilent_ci95_low": _csv_num(ns_ci[0]), "rmsae_nonsilent_ci95_high": _csv_num(ns_ci[1]),
            **{k: _csv_num(pooled.get(k)) for k in ("mae", "median", "p90", "within_5", "within_10", "within_20",
                                                     "within_30", "azimuth_mae")},
            "lag_s": _csv_num(s.get("lag_s")),
            "recordings": ";".join(f"{k}={_csv_num(per[k])}" for k in sorted(per, key=_rec_key)),
            "results_file": run.path, "results_sha256": run.sha256,
            "cells_run": task.get("cells_run", ""), "cells_total": task.get("cells_total", ""),
            "git_commit": (env.get("git") or {}).get("commit") or "",
            "git_dirty": str((env.get("git") or {}).get("dirty")).lower(),
            "weights_hash": tr.get("weights_hash") or ("untrained" if _untrained(r) else ""), "base_seed": task.get("base_seed"),
            "cpu": env.get("cpu"), "cpu_count": env.get("cpu_count"), "device": env.get("device"),
            "torch": env.get("torch"), "doabench": env.get("doabench"), "date": env.get("date"),
            "command": reproduce_command(r), "reference": "",
            "training_distribution": _distribution_csv(r),
        })
    methods: dict[str, list[ReferenceRow]] = {}
    for ref in board.references:
        methods.setdefault(ref.method, []).append(ref)
    for method, refs in sorted(methods.items()):
        avg = next((x.rmsae_all for x in refs if x.recording == "average"), None)
        recs = sorted((x for x in refs if x.recording != "average"), key=lambda x: _rec_key(x.recording))
        rows.append({"status": PUBLISHED, "task": board.task_id, "tracker": method, "rmsae_all": _csv_num(avg),
                     "recordings": ";".join(f"{x.recording}={_csv_num(x.rmsae_all)}" for x in recs),
                     "reference": f"{refs[0].source} ({refs[0].note})"})
    return _csv_text(rows, CSV_COLUMNS)


def _rec_key(s: str) -> tuple:
    return (0, int(s), "") if s.isdigit() else (1, 0, s)


CELL_COLUMNS = ("tracker", "t60", "snr", "n_episodes", "rmsae_all", "rmsae_all_ci95_low", "rmsae_all_ci95_high",
                "rmsae_nonsilent", "rmsae_nonsilent_ci95_low", "rmsae_nonsilent_ci95_high", "lag_s", "results_file")


def cells_csv(board: TaskBoard) -> str | None:
    """Long-format per-cell CSV of a grid task (None when no run has cells); partial runs' cells
    too, ``n_episodes`` saying how many of the cell's episodes they hold."""
    rows = []
    for run in sorted(board.runs + board.partial, key=lambda r: (r.tracker_id, r.path)):
        ids = _cell_ids(run)
        for (t, s), c in sorted(_cell_lookup(run).items()):
            a = shown_interval(run.results, "rmsae_all", ids[(t, s)]) or (None, None)
            n = shown_interval(run.results, "rmsae_nonsilent", ids[(t, s)]) or (None, None)
            rows.append({"tracker": run.tracker_id, "t60": _g(t), "snr": _g(s), "n_episodes": c.get("n_episodes"),
                         "rmsae_all": _csv_num(c.get("rmsae_all")), "rmsae_all_ci95_low": _csv_num(a[0]),
                         "rmsae_all_ci95_high": _csv_num(a[1]), "rmsae_nonsilent": _csv_num(c.get("rmsae_nonsilent")),
                         "rmsae_nonsilent_ci95_low": _csv_num(n[0]), "rmsae_nonsilent_ci95_high": _csv_num(n[1]),
                         "lag_s": _csv_num(c.get("lag_s")), "results_file": run.path})
    return _csv_text(rows, CELL_COLUMNS) if rows else None


def _locata_overall(boards: dict[str, TaskBoard]) -> list[str]:
    """Per tracker with runs on several recording tasks: the mean over tasks of the per-task means
    of per-recording RMSAEs (the paper's Table II "average" column)."""
    per: dict[str, dict[str, float]] = {}
    for task_id, board in boards.items():
        for run in board.runs:
            mean = recording_mean(run.results)
            if mean is not None:  # a configuration shown from several folders: one line per folder
                per.setdefault(_folder_cell(run), {}).setdefault(task_id, mean)
    rows = [(sum(v.values()) / len(v), t, v) for t, v in per.items() if len(v) > 1]
    if not rows:
        return []
    lines = ["", "## doabench averages over recording tasks (mean of the per-task means of recordings)", ""]
    return lines + _table(["tracker", "tasks", "RMSAE all, mean over tasks"],
                          [[t, ", ".join(sorted(v)), _num(m)] for m, t, v in sorted(rows)])


def _folder_cell(run: RunFile) -> str:
    """A tracker across tasks: its label, and its folder where its configuration is in several."""
    return f"`{run.tracker_id}`" + (f" (`{run.folder}`)" if run.in_several_folders else "")


def summary_markdown(boards: dict[str, TaskBoard], runs: Sequence[RunFile], references: Sequence[ReferenceRow],
                     command: str, reference_files: Sequence[str]) -> str:
    """``summary.md``: one line per task (best run), published overall rows, and every input file."""
    lines = ["# Leaderboards", "", "<!-- generated by `doabench leaderboard`; do not edit by hand -->", "",
             f"Regenerate with `{command}`. One page and one CSV per task; grid tasks also get "
             "`<task>-cells.csv`. Numbers in degrees (RMSAE over all frames, 95% bootstrap interval over episodes).",
             ""]
    rows = []
    for task_id, board in boards.items():
        best = board.runs[0] if board.runs else None
        rows.append([f"[`{task_id}`]({safe_name(task_id)}.md)",
                     str(len(board.runs)) + (f" (+{len(board.partial)} partial)" if board.partial else ""),
                     tracker_cell(best) if best else "—",
                     (_file_ci(best.results, "rmsae_all")
                      if recording_mean(best.results) is None else
                      f"{_num(recording_mean(best.results))} (mean of recordings)") if best else "—",
                     str(len({r.method for r in board.references})) if board.references else "0"])
    lines += _table(["task", "doabench runs", "best (RMSAE all)", "RMSAE all [95% CI]", "published methods"], rows)
    lines += _no_interval_legend(rows)
    lines += _locata_overall(boards)
    challenge = [(task_id, row) for task_id, board in boards.items()
                 for row in _locata_rows(board.runs[:1], {r.path: "" for r in board.runs[:1]})]
    if challenge:
        lines += ["", "## LOCATA challenge measures of the best runs", ""]
        lines += _table(("task",) + LOCATA_COLUMNS[:-1],
                        [[f"`{task_id}`"] + row[:-1] for task_id, row in challenge])
    overall = [r for r in references if r.task_id == "all"]
    if overall:
        lines += ["", "## Published overall averages (not reproduced)", "",
                  "Mean over the LOCATA tasks as printed in the source: " + "; ".join(sorted({r.source for r in overall}))
                  + ". No doabench run produced these numbers.", ""]
        lines += _table(["method", "RMSAE all frames (published)"],
                        [[r.method, _num(r.rmsae_all)] for r in sorted(overall, key=lambda r: (r.rmsae_all, r.method))])
    lines += ["", "## Inputs", ""]
    lines += [f"- `{run.path}` sha256 `{run.sha256}`" for run in runs]
    lines += [f"- `{path}` (published reference rows)" for path in reference_files]
    return "\n".join(lines) + "\n"


# -- the whole job -------------------------------------------------------------------------------------
DEFAULT_REFERENCE = "locata-paper-table2.csv"  # published rows kept beside the tables


def default_references(board_dir: str | Path) -> list[str]:
    """The reference CSVs a leaderboard folder uses when none are given: its
    :data:`DEFAULT_REFERENCE` if present (``doabench leaderboard`` and ``doabench sweep`` alike)."""
    path = Path(board_dir) / DEFAULT_REFERENCE
    return [str(path)] if path.is_file() else []


def build_leaderboards(results_dir: str | Path | Sequence[str | Path], reference_files: Sequence[str | Path] = (),
                       command: str = "doabench leaderboard") -> dict[str, str]:
    """All generated files as ``{file name: text}`` (nothing written), from the results files of
    one folder or several (:func:`doabench.results.ranking.load_runs`)."""
    runs = load_runs(results_dir)
    references = [row for path in reference_files for row in load_references(path)]
    boards = collect(runs, references)
    files: dict[str, str] = {}
    for task_id, board in boards.items():
        stem = safe_name(task_id)
        files[f"{stem}.md"] = task_markdown(board, command)
        files[f"{stem}.csv"] = task_csv(board)
        cells = cells_csv(board)
        if cells is not None:
            files[f"{stem}-cells.csv"] = cells
    files["summary.md"] = summary_markdown(boards, runs, references, command,
                                           [display_path(Path(p)) for p in reference_files])
    return dict(sorted(files.items()))


def write_leaderboards(files: dict[str, str], out_dir: str | Path) -> list[Path]:
    """Write the files atomically; unchanged files are left untouched (their mtime too)."""
    from doabench.files import write_text

    out_dir = Path(out_dir)
    written = []
    for name, text in files.items():
        path = out_dir / name
        if path.exists() and path.read_text() == text:
            continue
        write_text(path, text)
        written.append(path)
    return written


def stale_files(files: dict[str, str], out_dir: str | Path) -> list[str]:
    """Names of generated files whose committed copy in ``out_dir`` differs or is missing."""
    out_dir = Path(out_dir)
    return [name for name, text in files.items()
            if not (out_dir / name).is_file() or (out_dir / name).read_text() != text]
