"""The results dictionary of a run (schema ``doabench.results/2``; docs/results-format.md): the
scored frames and per-episode row of each episode, the pooled summary with its headline, the
scoring notes, the grid cells, the observations the tracker read, provenance and timings.

Frames where the tracker said "no source" (``doabench.NO_SOURCE``) are scored at the fixed error of
:mod:`doabench.metrics`; where a run has any, its rows count them (``no_estimate``,
``no_estimate_nonsilent``) and its summary gives their share (``no_estimate``). A run without
such frames has none of these keys: its results are what they always were."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from doabench.geometry import NO_SOURCE_ERROR_DEG, is_no_source
from doabench.envs.env import DoaEnv
from doabench.envs.registry import get_task_spec
from doabench.envs.spec import TaskSpec
from doabench.envs.selection import cells_covered
from doabench.metrics import (ScoredFrames, aggregate, bootstrap_ci, lag_from_curves, pooled_from_rows,
                              pooled_speed_bands, score_episode, score_frames)
from doabench.results.upgrade import RESULTS_SCHEMA
from doabench.trackers.base import Tracker


def score(ep: dict[str, Any]) -> ScoredFrames:
    """The scored frames of an episode record of the loop (:func:`doabench.metrics.score_frames`:
    invalid truth left out, planar arrays folded)."""
    return score_frames(ep["estimates"], ep["truth"], ep["vad"], ep.get("valid"), bool(ep.get("planar")))


def episode_row(index: int, ep: dict[str, Any]) -> dict[str, Any]:
    """The per-episode row of the results (scene parameters, timings, metrics of the scored frames:
    :func:`doabench.metrics.score_episode`)."""
    meta = ep["metadata"]
    scene = meta.get("scene", {}) if isinstance(meta.get("scene"), dict) else {}
    room = scene.get("room", {}) if isinstance(scene.get("room"), dict) else {}
    row = {"episode": index, "task": meta.get("task"), "seed": meta.get("seed"),
           "t60": room.get("t60", meta.get("t60")), "snr": scene.get("snr_db", meta.get("snr")),
           "recording": meta.get("recording"), "audio_s": ep["audio_s"], "tracker_s": ep["tracker_s"]}
    row.update(score_episode(ep["estimates"], ep["truth"], ep["vad"], ep.get("valid"), bool(ep.get("planar")),
                             ep.get("times")))
    row.update(no_estimate_counts(ep["estimates"], ep["vad"], ep.get("valid")))
    return row


def no_estimate_counts(estimates: Any, vad: Any, valid: Any = None) -> dict[str, int]:
    """``{"no_estimate": n, "no_estimate_nonsilent": m}``: the scored frames (valid truth) where the
    tracker said "no source", and the voice-active ones among them; empty when there are none."""
    none = is_no_source(np.asarray(estimates, np.float64).reshape(-1, 3))
    if valid is not None:
        none = none & np.asarray(valid, bool).reshape(-1)
    if not none.any():
        return {}
    return {"no_estimate": int(none.sum()), "no_estimate_nonsilent": int((none & np.asarray(vad, bool)).sum())}


def no_estimate_summary(rows: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The pooled share of scored frames without an estimate (``share_all``, ``share_nonsilent``
    of voice-active frames) and their counts, or None when every frame had one."""
    if not any("no_estimate" in r for r in rows):
        return None
    n = sum(int(r.get("no_estimate", 0)) for r in rows)
    n_active = sum(int(r.get("no_estimate_nonsilent", 0)) for r in rows)
    total, active = sum(int(r["n_frames"]) for r in rows), sum(int(r["n_nonsilent"]) for r in rows)
    return {"frames": n, "nonsilent_frames": n_active, "share_all": n / total if total else float("nan"),
            "share_nonsilent": n_active / active if active else float("nan"), "error_deg": NO_SOURCE_ERROR_DEG}


def lag_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Pooled lag (s, or None with the reason) and RMSAE per angular-speed band of some rows."""
    lag, note = lag_from_curves(rows)
    return {"lag_s": lag, **({"lag_note": note} if note else {}), "speed_bands": pooled_speed_bands(rows)}


def grid_cells(spec: TaskSpec, rows: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per-cell pooled RMSAEs with bootstrap CIs for a grid task, from the per-episode rows."""
    cells: dict[str, dict[str, Any]] = {}
    for task_id in spec.params.get("cells", []):
        sub = [r for r in rows if r["task"] == task_id]
        if sub:
            cell = get_task_spec(task_id).params["cell"]
            cells[task_id] = {"t60": cell["t60"], "snr": cell["snr"], **pooled_from_rows(sub), **lag_summary(sub)}
    return cells


def build_results(spec: TaskSpec, tracker: Tracker, tracker_text: str, tracker_options: Mapping[str, Any] | None,
                  env: DoaEnv, records: list[dict[str, Any]], wall_s: float, provenance: dict[str, Any], delays: str,
                  selection: dict[str, Any] | None = None) -> dict[str, Any]:
    """The results dictionary from the episode records of a run (``env``: its :class:`DoaEnv`;
    ``selection``: how its episodes were chosen, :func:`doabench.envs.selection.select_episodes`)."""
    rows = [r["row"] for r in records]
    per_frame = [(np.asarray(r["errors"], float), np.asarray(r["az_errors"], float), np.asarray(r["vad"], bool))
                 for r in records]
    agg = aggregate(per_frame, rows)
    ci_input = [(e, v) for e, _, v in per_frame]
    summary = {
        "rmsae_all": agg["pooled"]["rmsae_all"],
        "rmsae_nonsilent": agg["pooled"]["rmsae_nonsilent"],
        "rmsae_all_ci95": bootstrap_ci(ci_input, "rmsae_all"),
        "rmsae_nonsilent_ci95": bootstrap_ci(ci_input, "rmsae_nonsilent"),
        "pooled": agg["pooled"],
        "episode_mean": agg["episode_mean"],
        **lag_summary(rows),
    }
    if (none := no_estimate_summary(rows)) is not None:
        summary["no_estimate"] = none
    recording_rows = [r for r in rows if r.get("recording") is not None]
    # The task kind's scoring policy (LOCATA's, the paper's Table II: the mean of the per-recording
    # RMSAEs); a kind that declares none is scored by what its episodes are.
    policy = getattr(env.source, "headline", None) or ("recording_mean" if recording_rows else "pooled")
    if policy == "recording_mean" and recording_rows:
        summary["recording_mean"] = {k: float(np.mean([r[k] for r in recording_rows]))
                                     for k in ("rmsae_all", "rmsae_nonsilent")}
        summary["headline"] = {"metric": "rmsae_all", "aggregate": "recording_mean",
                               "value": summary["recording_mean"]["rmsae_all"]}
    else:
        summary["headline"] = {"metric": "rmsae_all", "aggregate": "pooled", "value": summary["rmsae_all"]}
    planar = any(r.get("planar") for r in records)
    source = env.source.describe()
    scoring = {"planar_fold": bool(planar), "invalid_frames_excluded": int(sum(r.get("frames_invalid", 0) for r in rows)),
               "headline": summary["headline"]["aggregate"]}
    if "vad" in source:
        scoring["vad"] = source["vad"]
    cells = grid_cells(spec, rows)
    audio_s = float(sum(r["audio_s"] for r in rows))
    tracker_s = float(sum(r["tracker_s"] for r in rows))
    results = {
        "schema": RESULTS_SCHEMA,
        "task": {"id": spec.id, "version": spec.version, "kind": spec.kind, "gym_id": spec.gym_id,
                 "base_seed": spec.base_seed, "episodes_run": len(rows), "episodes_total": env.n_episodes,
                 "complete": len(rows) == env.n_episodes,
                 "selection": selection or {"rule": "all", "episodes": None, "cells": None},
                 **(cells_covered(spec, rows) or {}), "source": source},
        "tracker": {"id": tracker_text, **tracker.describe(), "options": tracker_options or {},
                    **({"untrained": True} if getattr(tracker, "trained", True) is False else {})},
        "causal": bool(tracker.causal),
        "observations": env.observations.with_delays(delays).to_dict(),
        "environment": provenance,
        "summary": summary,
        "scoring": scoring,
        "cells": cells,
        "wall_time_s": wall_s,
        "audio_s": audio_s,
        "tracker_time_s": tracker_s,
        "real_time_factor": audio_s / wall_s if wall_s > 0 else None,
        "tracker_real_time_factor": audio_s / tracker_s if tracker_s > 0 else None,
        "episodes": rows,
        "frames": [r.get("frames") for r in records] if all("frames" in r for r in records) else None,
    }
    extra = [r["extra"] for r in records if "extra" in r]
    summarise = getattr(env.source, "summarise_extra", None)  # a task kind's own measures, under its key
    if extra and summarise is not None:
        results[str(getattr(env.source, "extra_key", "extra"))] = summarise(extra)
    return results
