"""The results dictionary of a run (schema ``doabench.results/1``; docs/results-format.md): the
scored frames and per-episode row of each episode, the pooled summary with its headline, the
scoring notes, the grid cells, provenance and timings."""
from __future__ import annotations

from typing import Any

import numpy as np

from doabench.envs.registry import get_task_spec
from doabench.metrics import (aggregate, bootstrap_ci, episode_metrics, lag_from_curves, motion_metrics,
                              pooled_from_rows, pooled_speed_bands)
from doabench.trackers.base import Tracker

RESULTS_SCHEMA = "doabench.results/1"


def scored_frames(ep: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(estimates, truth, vad)`` of the frames that are scored: frames whose truth is invalid
    (LOCATA ``valid_flag = 0``) are left out; for a planar array both estimate and truth are
    mirror-folded onto the upper half-space (the array cannot tell a direction from its mirror)."""
    keep = np.asarray(ep.get("valid", np.ones(len(ep["vad"]), bool)), dtype=bool)
    est, truth, vad = ep["estimates"][keep], ep["truth"][keep], np.asarray(ep["vad"], bool)[keep]
    if ep.get("planar"):
        from doabench.arrays import fold_to_upper

        est, truth = fold_to_upper(est), fold_to_upper(truth)
    return est, truth, vad


def _motion(ep: dict[str, Any]) -> dict[str, Any]:
    """Lag and angular-speed-band metrics of an episode (doabench.metrics) on its whole frame
    sequence (the delayed truth needs evenly spaced frames), scoring the voice-active valid frames;
    planar arrays folded as in :func:`scored_frames`."""
    times = np.asarray(ep.get("times", ()), dtype=np.float64)
    if len(times) < 2:
        return {"lag_s": None, "lag_note": "fewer than two frames: no defined lag"}
    period = float(np.median(np.diff(times)))
    est, truth = np.asarray(ep["estimates"], np.float64), np.asarray(ep["truth"], np.float64)
    if ep.get("planar"):
        from doabench.arrays import fold_to_upper

        est, truth = fold_to_upper(est), fold_to_upper(truth)
    use = np.asarray(ep["vad"], bool) & np.asarray(ep.get("valid", np.ones(len(truth), bool)), bool)
    return motion_metrics(est, truth, use, period)


def episode_row(index: int, ep: dict[str, Any]) -> dict[str, Any]:
    """The per-episode row of the results (scene parameters, timings, metrics of the scored frames)."""
    meta = ep["metadata"]
    scene = meta.get("scene", {}) if isinstance(meta.get("scene"), dict) else {}
    room = scene.get("room", {}) if isinstance(scene.get("room"), dict) else {}
    row = {"episode": index, "task": meta.get("task"), "seed": meta.get("seed"),
           "t60": room.get("t60", meta.get("t60")), "snr": scene.get("snr_db", meta.get("snr")),
           "recording": meta.get("recording"), "audio_s": ep["audio_s"], "tracker_s": ep["tracker_s"]}
    est, truth, vad = scored_frames(ep)
    row["frames_scored"] = int(len(vad))
    row["frames_invalid"] = int(len(ep["vad"]) - len(vad))
    row.update(episode_metrics(est, truth, vad))
    row.update(_motion(ep))
    return row


def lag_summary(rows: list[dict]) -> dict[str, Any]:
    """Pooled lag (s, or None with the reason) and RMSAE per angular-speed band of some rows."""
    lag, note = lag_from_curves(rows)
    return {"lag_s": lag, **({"lag_note": note} if note else {}), "speed_bands": pooled_speed_bands(rows)}


def grid_cells(spec, rows: list[dict]) -> dict[str, dict]:
    """Per-cell pooled RMSAEs with bootstrap CIs for a grid task, from the per-episode rows."""
    cells = {}
    for task_id in spec.params.get("cells", []):
        sub = [r for r in rows if r["task"] == task_id]
        if sub:
            cell = get_task_spec(task_id).params["cell"]
            cells[task_id] = {"t60": cell["t60"], "snr": cell["snr"], **pooled_from_rows(sub), **lag_summary(sub)}
    return cells


def build_results(spec, tracker: Tracker, tracker_text: str, tracker_options, env, records: list[dict],
                  wall_s: float, provenance: dict[str, Any], delays) -> dict[str, Any]:
    """The results dictionary from the episode records of a run (``env``: its :class:`DoaEnv`)."""
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
    recording_rows = [r for r in rows if r.get("recording") is not None]
    if recording_rows:
        # LOCATA (the paper's Table II): the mean of the per-recording RMSAEs is the headline.
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
    return {
        "schema": RESULTS_SCHEMA,
        "task": {"id": spec.id, "version": spec.version, "kind": spec.kind, "gym_id": spec.gym_id,
                 "base_seed": spec.base_seed, "episodes_run": len(rows), "episodes_total": env.n_episodes,
                 "source": source},
        "tracker": {"id": tracker_text, **tracker.describe(), "options": tracker_options or {},
                    **({"untrained": True} if getattr(tracker, "trained", True) is False else {})},
        "causal": bool(tracker.causal),
        "features": {"kinds": list(env.features), "resolution": "%dx%d" % env.resolution, "delays": delays,
                     "frame": env.frame_spec.to_dict()},
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
