"""Run a tracker on a task and score it: what ``doabench run`` does.

Per episode the runner resets the environment, resets the tracker with the array, then either
steps frame by frame (causal trackers) or hands the whole episode over (offline trackers). Every
direction the tracker returns is checked (shape (3,), finite, non-zero) before it reaches the
environment. Finished episodes are appended to a ``.partial.jsonl`` file next to the results, so
an interrupted run continues where it stopped when run again with the same settings.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
import time
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import numpy as np

from doabench.envs.env import DoaEnv
from doabench.envs.registry import get_task_spec
from doabench.errors import ConfigError, DoabenchError, InputError, TrackerError
from doabench.geometry import normalize
from doabench.metrics import aggregate, pooled_from_rows, azimuth_errors_deg, bootstrap_ci, episode_metrics, frame_errors_deg
from doabench.results.files import to_json
from doabench.results.provenance import environment
from doabench.trackers.base import Tracker
from doabench.trackers.registry import make_tracker

RESULTS_SCHEMA = "doabench.results/1"


def check_direction(tracker: Tracker, d: Any, frame: int) -> np.ndarray:
    """A tracker's output as a unit vector, or a TrackerError naming the tracker."""
    try:
        a = np.asarray(d, dtype=np.float64)
    except (TypeError, ValueError):
        raise TrackerError(f"tracker {tracker.name!r} returned {type(d).__name__} at frame {frame}, "
                           "not a direction vector") from None
    if a.shape != (3,):
        raise TrackerError(f"tracker {tracker.name!r} returned shape {a.shape} at frame {frame}; expected (3,)")
    if not np.all(np.isfinite(a)):
        raise TrackerError(f"tracker {tracker.name!r} returned a non-finite direction {a} at frame {frame}")
    if not np.any(a):
        raise TrackerError(f"tracker {tracker.name!r} returned a zero vector at frame {frame}")
    return normalize(a)  # scaled by its largest component first: [1e200, 0, 0] is the x axis, not 0


def check_directions(tracker: Tracker, d: Any, n_frames: int) -> np.ndarray:
    """The offline path's ``(T, 3)`` output, checked like :func:`check_direction`."""
    a = np.asarray(d, dtype=np.float64)
    if a.shape != (n_frames, 3):
        raise TrackerError(f"tracker {tracker.name!r} returned shape {a.shape}; expected ({n_frames}, 3)")
    bad = ~np.all(np.isfinite(a), axis=1) | ~np.any(a, axis=1)
    if bad.any():
        raise TrackerError(f"tracker {tracker.name!r} returned a non-finite or zero direction at frame "
                           f"{int(np.argmax(bad))}")
    return normalize(a)


def _guarded(tracker: Tracker, what: str, fn: Callable, *args: Any) -> Any:
    """Call a tracker method; an exception it raises becomes a one-line TrackerError naming it."""
    try:
        return fn(*args)
    except DoabenchError:
        raise
    except Exception as exc:
        from doabench.trackers.registry import one_line

        raise TrackerError(f"tracker {tracker.name!r} raised in {what}: {one_line(exc)}") from None


def check_trained(tracker: Tracker, keyword: bool = False) -> None:
    """Refuse to run a learned tracker that has no trained weights, unless it was asked for on
    purpose (``weights=random``: the tracker's ``allow_untrained``). Trackers without a ``trained``
    attribute (the classical ones) always pass. ``keyword``: word the hint for Python callers."""
    if getattr(tracker, "trained", True) is not False or getattr(tracker, "allow_untrained", False):
        return
    res = getattr(tracker, "resolution", None)
    what = f" for {res[0]}x{res[1]} maps" if getattr(tracker, "uses_resolution", False) and res else ""
    if keyword:
        hint = "pass tracker_options={'weights': FILE}, or {'weights': 'random'} to run the untrained model on purpose"
    else:
        hint = "pass --tracker-opt weights=FILE, or --tracker-opt weights=random to run the untrained model on purpose"
    raise ConfigError(f"tracker {tracker.name!r} has no trained weights{what}; {hint}")


def make_env_for(tracker: Tracker, task: str, device: str | None = None, delays: str = "nearest",
                 **env_options: Any) -> DoaEnv:
    """The environment configured with the features, resolution and frames a tracker needs."""
    spec = get_task_spec(task)
    frame_spec = tracker.frame_spec
    if frame_spec.fs != spec.frames.fs:
        raise ConfigError(f"tracker {tracker.name!r} needs {frame_spec.fs} Hz audio; task {spec.id!r} is "
                          f"{spec.frames.fs} Hz")
    return DoaEnv(spec, features=tuple(tracker.features), resolution=tracker.resolution or (16, 32),
                  delays=delays, frame_spec=frame_spec, device=device, **env_options)


def run_episode(env: DoaEnv, tracker: Tracker, index: int) -> dict[str, Any]:
    """One episode: returns estimates, truth, vad, times and timings."""
    obs, info = env.reset(options={"episode": index})
    n = info["n_frames"]
    episode = env._episode
    _guarded(tracker, f"reset() of episode {index}",
             lambda: tracker.reset(episode.array or env.array, frame_spec=env.frame_spec, task=env.spec_task.id,
                                   metadata=episode.metadata))
    start = time.perf_counter()
    if tracker.causal:
        estimates = np.zeros((n, 3))
        for t in range(n):
            estimates[t] = check_direction(tracker, _guarded(tracker, f"step() at frame {t} of episode {index}",
                                                             tracker.step, obs), t)
            obs, _, terminated, _, _ = env.step(estimates[t].astype(np.float32))
    else:
        estimates = check_directions(tracker, _guarded(tracker, f"track() of episode {index}", tracker.track,
                                                       env.offline_episode()), n)
    tracker_s = time.perf_counter() - start
    truth = env.episode_truth()
    array = episode.array or env.array
    valid = np.asarray(truth.get("valid", np.ones(n, bool)), dtype=bool)
    return {"estimates": estimates, "truth": truth["directions"], "vad": truth["vad"], "times": truth["times"],
            "valid": valid, "planar": bool(array.planar),
            "tracker_s": tracker_s, "audio_s": episode.n_samples / episode.fs, "metadata": episode.metadata}


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


def lock_path(partial_path: str | Path) -> Path:
    """The lock file of a run's resume journal."""
    p = Path(partial_path)
    return p.with_name(p.name.removesuffix(".partial.jsonl") + ".lock")


@contextlib.contextmanager
def run_lock(partial_path: str | Path) -> Iterator[None]:
    """Exclusive ``flock`` of the run writing ``partial_path`` (two runs with the same ``--out``,
    task and tracker would otherwise overwrite each other's journal and results). The kernel
    releases it if the process dies; the lock file is removed when the run ends."""
    import fcntl

    path = lock_path(partial_path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise InputError(f"another doabench run is writing {Path(partial_path).parent} for this task and "
                             f"tracker (its lock {path.name} is held); wait for it or stop it") from None
        try:
            yield
        finally:
            path.unlink(missing_ok=True)
    finally:
        os.close(fd)


def _config_hash(config: dict) -> str:
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _episode_row(index: int, ep: dict[str, Any]) -> dict[str, Any]:
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
    return row


def run_task(tracker: Tracker | str, task: str, episodes: int | Sequence[int] | None = None,
             device: str | None = None, delays: str = "nearest", tracker_options: dict | None = None,
             partial_path: str | Path | None = None, progress: bool | Callable = True,
             keep_frames: bool = True, lock: bool = True, **env_options: Any) -> dict[str, Any]:
    """Run ``tracker`` on ``task`` and return the results dictionary (see docs/results-format).

    ``episodes``: a count (the first N) or explicit indices; default all of the task's episodes.
    ``partial_path``: a JSON-lines file of finished episodes for resuming; removed by the caller
    once the final results are written. It is locked for the run (``lock=False``: the caller holds
    :func:`run_lock` already). ``wall_time_s`` adds up every invocation that contributed episodes.
    """
    if partial_path and lock:
        with run_lock(partial_path):
            return run_task(tracker, task, episodes, device, delays, tracker_options, partial_path, progress,
                            keep_frames, lock=False, **env_options)
    if isinstance(tracker, str):
        tracker_text = tracker
        tracker = make_tracker(tracker, **(tracker_options or {}))
    else:
        tracker_text = tracker.name
    check_trained(tracker, keyword=True)
    spec = get_task_spec(task)
    provenance = environment(device)  # taken before the work: the code that runs is the code recorded
    wall_start = time.perf_counter()
    env = make_env_for(tracker, task, device=device, delays=delays, **env_options)
    n_total = env.n_episodes
    if episodes is None:
        indices = list(range(n_total))
    elif isinstance(episodes, int):
        if episodes < 1:
            raise ConfigError(f"--episodes must be at least 1, got {episodes}")
        indices = list(range(min(episodes, n_total)))
    else:
        indices = [int(i) for i in episodes]
    config = {"task": spec.id, "task_version": spec.version, "tracker": tracker_text,
              "options": tracker_options or {}, "delays": delays, "indices": indices,
              "weights": tracker.weights_hash(), "env": {k: str(v) for k, v in env_options.items()}}
    done = _load_partial(partial_path, _config_hash(config))
    try:
        records = _run_indices(env, tracker, spec, indices, done, partial_path, progress, keep_frames, wall_start)
    except BaseException:
        if partial_path and not done:  # nothing finished: leave no journal behind
            Path(partial_path).unlink(missing_ok=True)
        raise
    # This invocation's wall time plus that of the episodes earlier invocations journalled.
    earlier = sum(float(r.get("wall_s", 0.0)) for r in records if not r.pop("_new", False))
    wall_s = earlier + (time.perf_counter() - wall_start)
    return _results(spec, tracker, tracker_text, tracker_options, env, records, wall_s, provenance, delays)


def _run_indices(env, tracker, spec, indices, done, partial_path, progress, keep_frames, wall_start) -> list[dict]:
    """Run the episodes not yet in ``done``, journalling each; returns the records in index order."""
    last = wall_start
    bar = None
    if progress is True:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(indices), initial=len(done), desc=f"{tracker.name} on {spec.id}", unit="episode")
    for index in indices:
        if index in done:
            continue
        ep = run_episode(env, tracker, index)
        est, truth, vad = scored_frames(ep)
        record = {"row": _episode_row(index, ep), "errors": frame_errors_deg(est, truth),
                  "az_errors": azimuth_errors_deg(est, truth), "vad": vad, "planar": ep["planar"]}
        if keep_frames:
            record["frames"] = {"times": ep["times"], "estimates": ep["estimates"], "truth": ep["truth"],
                                "vad": ep["vad"]}
            if not ep["valid"].all():
                record["frames"]["valid"] = ep["valid"]
        now = time.perf_counter()
        record["wall_s"] = now - last  # this episode's share of the wall time, summed over resumes
        last = now
        record = json.loads(to_json(record, indent=None))
        if partial_path:
            with open(partial_path, "a") as f:
                f.write(to_json(record, indent=None) + "\n")
        record["_new"] = True
        done[index] = record
        if bar is not None:
            bar.update(1)
            bar.set_postfix(rmsae=f"{record['row']['rmsae_all']:.1f}")
        elif callable(progress):
            progress(index, record)
    if bar is not None:
        bar.close()
    return [done[i] for i in indices]


def grid_cells(spec, rows: list[dict]) -> dict[str, dict]:
    """Per-cell pooled RMSAEs with bootstrap CIs for a grid task, from the per-episode rows."""
    cells = {}
    for task_id in spec.params.get("cells", []):
        sub = [r for r in rows if r["task"] == task_id]
        if sub:
            cell = get_task_spec(task_id).params["cell"]
            cells[task_id] = {"t60": cell["t60"], "snr": cell["snr"], **pooled_from_rows(sub)}
    return cells


def _load_partial(path: str | Path | None, config_hash: str) -> dict[int, dict]:
    """Finished episodes of an interrupted run with the same configuration.

    The journal is rewritten with its valid lines only, so a line cut by a crash is dropped (that
    episode is redone) instead of having the next episode's line appended to the fragment. A
    header that is not doabench's is a one-line error: the file is left for the user to look at.
    """
    if not path:
        return {}
    path = Path(path)
    done: dict[int, dict] = {}
    keep: list[str] = []
    if path.exists():
        try:
            lines = path.read_text().splitlines()
            header = json.loads(lines[0]) if lines else {}
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            header = None
        if not isinstance(header, dict) or (lines and not isinstance(header.get("config"), str)):
            raise InputError(f"resume journal {path} is not a doabench run journal (bad first line); delete it "
                             "to start the run afresh")
        if header.get("config") == config_hash:
            for line in lines[1:]:
                try:
                    rec = json.loads(line)
                    index = int(rec["row"]["episode"])
                    if not isinstance(rec.get("errors"), list):
                        raise TypeError
                except (json.JSONDecodeError, KeyError, TypeError, ValueError):
                    continue  # a line cut by a crash: that episode is redone
                done[index] = rec
                keep.append(line)
    from doabench.results.files import write_text

    write_text(path, "".join(line + "\n" for line in [json.dumps({"config": config_hash})] + keep))
    return done


def _results(spec, tracker: Tracker, tracker_text: str, tracker_options, env: DoaEnv, records: list[dict],
             wall_s: float, provenance: dict[str, Any], delays) -> dict[str, Any]:
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
