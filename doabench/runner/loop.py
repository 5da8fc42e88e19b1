"""The evaluation loop: a tracker over a task's episodes, scored (what ``doabench run`` does).

Per episode the loop resets the environment, resets the tracker with the array and
:func:`reset_context` (frames and task id: nothing about the scene or the truth), then either
steps frame by frame (causal trackers) or hands the whole episode over (offline trackers):
:func:`track_frames`, which ``doabench track`` can share. The truth and the episode's metadata
(for the results) are read from the environment once every frame has been scored. Every
direction the tracker returns is checked (shape (3,), finite, non-zero, or three NaNs: "no
source", :data:`doabench.geometry.NO_SOURCE`) before it reaches the environment. Finished episodes are journalled (:mod:`doabench.runner.journal`), so an interrupted run continues where it stopped
when run again with the same settings; :mod:`doabench.runner.summary` assembles the results.
"""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence, TypeVar

import numpy as np

from doabench.envs.env import DoaEnv
from doabench.envs.registry import get_task_spec
from doabench.envs.sources import say_simulation_time, task_identity
from doabench.envs.spec import TaskSpec
from doabench.errors import ConfigError, DoabenchError, TrackerError
from doabench.geometry import NO_SOURCE, is_no_source, normalize
from doabench.files import to_json
from doabench.provenance import environment
from doabench.runner.journal import append_record, config_hash, load_journal
from doabench.runner.episode_cache import cache_episodes
from doabench.envs.selection import select_episodes
from doabench.runner.summary import build_results, episode_row, score
from doabench.trackers.base import Tracker, observations_of

T = TypeVar("T")
#: ``progress`` of a run: a tqdm bar (True), none (False), or ``fn(episode index, its journal record)``
#: called as each episode finishes
Progress = bool | Callable[[int, dict[str, Any]], object]


#: how a refused non-finite output is told what "no source" is
_NO_SOURCE_HINT = "(to say no source, return three NaNs: doabench.NO_SOURCE)"


def check_direction(tracker: Tracker, d: Any, frame: int) -> np.ndarray:
    """A tracker's output as a unit vector, or three NaNs where it says "no source"
    (:data:`~doabench.geometry.NO_SOURCE`), or a TrackerError naming the tracker."""
    try:
        a = np.asarray(d, dtype=np.float64)
    except (TypeError, ValueError):
        raise TrackerError(f"tracker {tracker.name!r} returned {type(d).__name__} at frame {frame}, "
                           "not a direction vector") from None
    if a.shape != (3,):
        raise TrackerError(f"tracker {tracker.name!r} returned shape {a.shape} at frame {frame}; expected (3,)")
    if is_no_source(a):
        return np.array(NO_SOURCE)  # a writable copy
    if not np.all(np.isfinite(a)):
        raise TrackerError(f"tracker {tracker.name!r} returned a non-finite direction {a} at frame {frame} "
                           f"{_NO_SOURCE_HINT}")
    if not np.any(a):
        raise TrackerError(f"tracker {tracker.name!r} returned a zero vector at frame {frame}")
    # scaled by its largest component first: [1e200, 0, 0] is the x axis, not 0
    return normalize(a)


def check_directions(tracker: Tracker, d: Any, n_frames: int) -> np.ndarray:
    """The offline path's ``(T, 3)`` output, checked like :func:`check_direction` (rows of three
    NaNs say "no source" and stay NaN)."""
    try:
        a = np.asarray(d, dtype=np.float64)
    except (TypeError, ValueError):
        raise TrackerError(f"tracker {tracker.name!r} returned {type(d).__name__} from track(), "
                           "not directions") from None
    if a.shape != (n_frames, 3):
        raise TrackerError(f"tracker {tracker.name!r} returned shape {a.shape}; expected ({n_frames}, 3)")
    none = is_no_source(a)
    bad = ~none & (~np.all(np.isfinite(a), axis=1) | ~np.any(a, axis=1))
    if bad.any():
        t = int(np.argmax(bad))
        raise TrackerError(f"tracker {tracker.name!r} returned a non-finite or zero direction {a[t]} at frame "
                           f"{t} {_NO_SOURCE_HINT}")
    out = np.full_like(a, np.nan)
    out[~none] = normalize(a[~none])
    return out


def guarded(tracker: Tracker, what: str, fn: Callable[..., T], *args: Any) -> T:
    """Call a tracker method; an exception it raises becomes a one-line TrackerError naming it."""
    try:
        return fn(*args)
    except DoabenchError:
        raise
    except Exception as exc:
        from doabench.errors import one_line

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


def make_env_for(tracker: Tracker, task: str | TaskSpec, device: str | None = None, delays: str | None = None,
                 **env_options: Any) -> DoaEnv:
    """The environment giving the observations a tracker reads (its ``observation_spec``), on
    ``delays`` when given (another delay mode on purpose), else on the tracker's own."""
    spec = get_task_spec(task)
    wanted = observations_of(tracker).with_delays(delays)
    if wanted.frames.fs != spec.frames.fs:
        raise ConfigError(f"tracker {tracker.name!r} needs {wanted.frames.fs} Hz audio; task {spec.id!r} is "
                          f"{spec.frames.fs} Hz")
    return DoaEnv(spec, wanted, device=device, **env_options)


def step_frame(tracker: Tracker, observation: Any, t: int, where: str = "") -> np.ndarray:
    """One causal step: ``tracker.step(observation)`` for frame ``t``, guarded and checked (a unit
    vector ``(3,)``, or three NaNs: no source); ``where`` ends the error messages."""
    return check_direction(tracker, guarded(tracker, f"step() at frame {t}{where}", tracker.step, observation), t)


def track_frames(tracker: Tracker, n_frames: int, first: Any, advance: Callable[[int, np.ndarray], Any],
                 offline: Callable[[], Mapping[str, np.ndarray]], where: str = "") -> np.ndarray:
    """A reset tracker's ``(n_frames, 3)`` checked unit directions (three NaNs where it said no source).

    Causal trackers: ``step(obs)`` per frame, starting from observation ``first``;
    ``advance(t, direction)`` is called with each frame's checked direction and returns the next
    observation. Offline trackers: ``track(offline())``. ``where`` ends the error messages
    (``" of episode 3"``).
    """
    if not tracker.causal:
        return check_directions(tracker, guarded(tracker, f"track(){where}", tracker.track, offline()), n_frames)
    estimates = np.zeros((n_frames, 3))
    obs = first
    for t in range(n_frames):
        estimates[t] = step_frame(tracker, obs, t, where)
        obs = advance(t, estimates[t])
    return estimates


def reset_context(env: DoaEnv) -> dict[str, Any]:
    """The keyword arguments of ``tracker.reset(array, **context)`` for the episode ``env`` has
    just reset: what a deployed tracker knows too (:class:`~doabench.trackers.base.ResetContext`),
    the frames and the task id. Never the episode's metadata, truth or seed."""
    return {"frame_spec": env.frame_spec, "task": env.spec_task.id}


def run_episode(env: DoaEnv, tracker: Tracker, index: int) -> dict[str, Any]:
    """One episode: returns estimates, truth, vad, times, metadata and timings.

    The tracker gets the array, :func:`reset_context` and the observations; the truth and the
    metadata are read from the environment once every frame has been scored."""
    obs, info = env.reset(options={"episode": index})
    n = info["n_frames"]
    array = env.episode_array
    context = reset_context(env)
    guarded(tracker, f"reset() of episode {index}", lambda: tracker.reset(array, **context))
    start = time.perf_counter()
    estimates = track_frames(tracker, n, obs, lambda t, d: env.step(d.astype(np.float32))[0], env.offline_episode,
                             where=f" of episode {index}")
    tracker_s = time.perf_counter() - start
    if not env.episode_over:  # the offline path: the tracker's whole output is scored at once
        env.score_offline(estimates)
    truth = env.episode_truth()
    episode = env.current_episode
    valid = np.asarray(truth.get("valid", np.ones(n, bool)), dtype=bool)
    return {"estimates": estimates, "truth": truth["directions"], "vad": truth["vad"], "times": truth["times"],
            "valid": valid, "planar": bool(array.planar),
            "tracker_s": tracker_s, "audio_s": episode.n_samples / episode.fs, "metadata": env.episode_metadata()}


def execute_spec(spec: Any, tracker: Tracker, partial_path: str | Path | None,
                 episodes: int | Sequence[int] | None, cells: Sequence[str] | None, device: str | None,
                 progress: Progress, keep_frames: bool, env_options: dict[str, Any]) -> dict[str, Any]:
    """Run the :class:`~doabench.runner.spec.RunSpec` ``spec`` with ``tracker`` (its instance) and
    return the results dictionary. ``partial_path``: the resume journal (None: no journal), held
    locked by the caller. ``wall_time_s`` adds up every invocation that contributed episodes."""
    check_trained(tracker, keyword=True)
    task = spec.resolved_task()  # resolved once, where the run was built
    identity = task_identity(task, env_options)
    if identity != dict(spec.task_options):  # the file's name and content must name the same episodes
        raise ConfigError(f"this run of {task.id} was named for the task options {dict(spec.task_options)} and runs "
                          f"with {identity}: build its RunSpec with the same options (RunSpec.build(..., env_options=...))")
    provenance = environment(device)  # taken before the work: the code that runs is the code recorded
    wall_start = time.perf_counter()
    env = make_env_for(tracker, task, device=device, delays=spec.delays, **env_options)
    cache_episodes(env)  # DOABENCH_EPISODE_CACHE: several trackers, one simulation per episode
    indices, selection = select_episodes(task, env.n_episodes, episodes, cells)
    done = load_journal(partial_path, config_hash(spec.journal_config(indices, env_options)))
    earlier = set(done)  # episodes an earlier invocation journalled
    say_simulation_time(env.source, [i for i in indices if i not in done])  # a slow engine says so first
    try:
        records = _run_indices(env, tracker, task, indices, done, partial_path, progress, keep_frames, wall_start)
    except BaseException:
        if partial_path and not done:  # nothing finished, now or before: leave no journal behind
            Path(partial_path).unlink(missing_ok=True)
        raise
    # This invocation's wall time plus that of the episodes earlier invocations journalled.
    wall_s = sum(float(done[i].get("wall_s", 0.0)) for i in indices if i in earlier) + (time.perf_counter() - wall_start)
    results = build_results(task, tracker, spec.tracker, dict(spec.options), env, records, wall_s, provenance,
                            spec.delays, selection)
    if spec.trained_delays is not None:
        results["trained_delays"] = spec.trained_delays
    if spec.given_id is not None:
        results["tracker"]["given_id"] = spec.given_id
    results["task"]["options"] = identity
    return results


def _run_indices(env: DoaEnv, tracker: Tracker, spec: TaskSpec, indices: list[int], done: dict[int, dict[str, Any]],
                 partial_path: str | Path | None, progress: Progress, keep_frames: bool,
                 wall_start: float) -> list[dict[str, Any]]:
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
        scored = score(ep)
        record: dict[str, Any] = {"row": episode_row(index, ep), "errors": scored.errors,
                                  "az_errors": scored.az_errors, "vad": scored.vad, "planar": ep["planar"]}
        extra = getattr(env.source, "extra_scores", None)  # a task kind's own measures (LOCATA's)
        if extra is not None and (scores := extra(index, ep["metadata"], ep["times"], ep["estimates"],
                                                  env.frame_spec)) is not None:
            record["extra"] = scores
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
            append_record(partial_path, record)
        done[index] = record
        if bar is not None:
            bar.update(1)
            bar.set_postfix(rmsae=f"{record['row']['rmsae_all']:.1f}")
        elif callable(progress):
            progress(index, record)
    if bar is not None:
        bar.close()
    return [done[i] for i in indices]
