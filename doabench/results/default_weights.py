"""The rule that chooses a tracker's default weights among its shipped ones (docs/models.md):

    Among a tracker's shipped weights whose pooled lag on ``sim-walk`` and on ``sim-turn`` is at
    most 0.3 s, the one with the lowest mean of the pooled all-frames RMSAE over ``sim-grid``,
    ``sim-walk`` and ``sim-turn``. Only complete runs count; weights without a complete run of each
    of the three tasks, or without a defined lag on a moving task, are not eligible. Where none is
    eligible, the default is the tracker's plain weights.

Pure functions of results dictionaries (the committed ``results/`` for the shipped catalog; a
test's own files in the tests): which runs count, their figures, each candidate's verdict and the
choice. The candidates and the plain weights to fall back on are the caller's to give: which
weights ship, their names, files and SHA-256 are the catalog's (``doabench_baselines.catalog``),
which ``scripts/weights_catalog.py`` asks before it applies this rule and writes the catalog.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterable, Mapping

from doabench.results.identity import canonical_id, results_delays

#: the tasks whose mean pooled RMSAE (all frames) ranks the eligible weights
RULE_TASKS = ("sim-grid", "sim-walk", "sim-turn")
#: the moving-talker tasks whose pooled lag decides eligibility
LAG_TASKS = ("sim-walk", "sim-turn")
MAX_LAG_S = 0.3


@dataclass(frozen=True)
class Verdict:
    """Why one candidate is or is not eligible, and its score (the mean RMSAE, or None)."""

    name: str
    eligible: bool
    score: float | None
    reason: str


def counted_runs(runs: Iterable[Mapping[str, Any]], tracker: str, weights_hash: str) -> dict[str, Mapping[str, Any]]:
    """Per task, the run the rule counts for ``tracker`` (canonical id) with these weights: a
    complete run on the task's defaults (no task options, no tracker option but ``weights``, the
    ``nearest`` SRP delays); the last such run where a task has several."""
    out: dict[str, Mapping[str, Any]] = {}
    for r in runs:
        task, trk = r.get("task") or {}, r.get("tracker") or {}
        if trk.get("weights_hash") != weights_hash or canonical_id(dict(r)) != tracker:
            continue
        if task.get("episodes_run") != task.get("episodes_total") or task.get("options"):
            continue
        if set(trk.get("options") or {}) - {"weights"} or results_delays(r) != "nearest":
            continue
        out[str(task.get("id"))] = r
    return out


def headline(runs: Iterable[Mapping[str, Any]], tracker: str, weights_hash: str) -> dict[str, dict[str, Any]]:
    """Per task, the figures of the run :func:`counted_runs` counts:
    ``{"sim-walk": {"rmsae_all", "rmsae_nonsilent", "lag_s", "episodes"}}`` (two decimals)."""
    out: dict[str, dict[str, Any]] = {}
    for task, r in counted_runs(runs, tracker, weights_hash).items():
        s = r.get("summary") or {}
        lag = s.get("lag_s")
        out[task] = {"rmsae_all": round(float(s["rmsae_all"]), 2),
                     "rmsae_nonsilent": round(float(s["rmsae_nonsilent"]), 2),
                     "lag_s": None if lag is None else round(float(lag), 2),
                     "episodes": int((r.get("task") or {}).get("episodes_run") or 0)}
    return dict(sorted(out.items()))


def judge(name: str, figures: Mapping[str, Mapping[str, Any]]) -> Verdict:
    """The rule for one candidate with its :func:`headline` figures."""
    missing = [t for t in RULE_TASKS if t not in figures]
    if missing:
        return Verdict(name, False, None, f"no complete run of {', '.join(missing)}")
    for task in LAG_TASKS:
        lag = figures[task].get("lag_s")
        if lag is None or not math.isfinite(float(lag)):
            return Verdict(name, False, None, f"no defined lag on {task}")
        if float(lag) > MAX_LAG_S + 1e-9:
            return Verdict(name, False, None, f"lags {float(lag):.2f} s on {task} (> {MAX_LAG_S:g} s)")
    score = sum(float(figures[t]["rmsae_all"]) for t in RULE_TASKS) / len(RULE_TASKS)
    return Verdict(name, True, score, f"mean RMSAE {score:.2f} deg over {', '.join(RULE_TASKS)}")


def choose(candidates: Mapping[str, Mapping[str, Mapping[str, Any]]], plain: str | None) -> tuple[str | None, list[Verdict]]:
    """The default among ``candidates`` (``{name: headline figures}``) and every candidate's verdict:
    the eligible one with the lowest score (ties: the name first in sorted order), else ``plain``."""
    verdicts = [judge(n, candidates[n]) for n in sorted(candidates)]
    eligible = [v for v in verdicts if v.eligible]
    if not eligible:
        return plain, verdicts
    return min(eligible, key=lambda v: (v.score, v.name)).name, verdicts
