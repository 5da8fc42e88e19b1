"""``doabench sweep``: every (tracker, task) run into one results folder, then its leaderboard.

Each run is what ``doabench run --tracker A --task X --out DIR`` does, with the same resume
journal (``DIR/.<task>__<tracker>.partial.jsonl``) and lock (:func:`doabench.runner.journal.run_lock`),
so a sweep killed at any moment continues, when run again, with the finished runs skipped (their
results file is there and matches the settings), the interrupted ones resumed from their
journals and the rest started. Locally the runs go one after another; with ``engine="ray"`` each
run is a Ray task (one CPU) on a cluster or a local Ray instance, and the driver writes every
results file as it arrives. A run that fails is reported and the others go on.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

from doabench.errors import ConfigError, DoabenchError, OutputError
from doabench.trackers.base import resolve_delays


@dataclass
class SweepRun:
    tracker: str
    task: str
    status: str = "pending"  # done | skipped | failed
    json_path: Path | None = None
    rmsae_all: float | None = None
    error: str = ""
    seconds: float = 0.0


@dataclass
class SweepResult:
    out: Path
    runs: list[SweepRun]
    leaderboard: Path | None = None
    leaderboard_files: list[str] = field(default_factory=list)

    @property
    def failed(self) -> list[SweepRun]:
        return [r for r in self.runs if r.status == "failed"]


def parse_list(text: str | Sequence[str], what: str) -> list[str]:
    items = [s.strip() for s in (text.split(",") if isinstance(text, str) else text)]
    items = [s for s in items if s]
    if not items:
        raise ConfigError(f"--{what} needs at least one id (comma-separated)")
    return list(dict.fromkeys(items))  # duplicates once, order kept


def run_stem(task_id: str, tracker_id: str, options: dict[str, Any] | None = None, delays: str = "nearest") -> str:
    """The results file stem ``doabench run`` gives this configuration (options, delays and a
    ``weights=FILE``'s content hash included), so a sweep finds its own finished runs."""
    from doabench.results.provenance import sha256_file
    from doabench.results.writer import results_stem

    weights = (options or {}).get("weights")
    weights_hash = sha256_file(weights) if weights and Path(str(weights)).is_file() else None
    return results_stem(task_id, tracker_id, options, delays, weights_hash)


def partial_path_for(out: Path, task_id: str, tracker_id: str, options: dict[str, Any] | None = None,
                     delays: str = "nearest") -> Path:
    return out / f".{run_stem(task_id, tracker_id, options, delays)}.partial.jsonl"


def finished_results(out: Path, task_id: str, tracker_id: str, episodes: int | None, delays: str,
                     options: dict[str, Any], weights_hash: str | None = None,
                     tracker_version: str | None = None) -> Path | None:
    """The results file of a finished run with these settings, else None (the run is (re)done).

    ``weights_hash``: the tracker's weights now (``Tracker.weights_hash()``); a file written with
    other weights (e.g. before new shipped weights) is not finished for this sweep. Likewise a
    file written by another ``tracker_version`` (``Tracker.version``) when one is given."""
    from doabench.envs.registry import get_task_spec
    from doabench.results.writer import configuration, results_configuration

    path = out / f"{run_stem(task_id, tracker_id, options, delays)}.json"
    if not path.is_file() or partial_path_for(out, task_id, tracker_id, options, delays).exists():
        return None
    try:
        r = json.loads(path.read_text())
        spec = get_task_spec(task_id)
        total = int(r["task"]["episodes_total"])
        want = total if episodes is None else min(int(episodes), total)
        # the same configuration (results.writer.configuration: task and version, tracker, options,
        # weights, delays), as many episodes, and the same tracker version
        same = (results_configuration(r) == configuration(spec.id, spec.version, tracker_id, options,
                                                          weights_hash, delays)
                and int(r["task"]["episodes_run"]) == want
                and (tracker_version is None or str(r["tracker"].get("version")) == str(tracker_version)))
    except (OSError, ValueError, KeyError, TypeError, DoabenchError):
        return None
    return path if same else None


def execute_run(tracker_id: str, task_id: str, out: str | Path, episodes: int | None, delays: str,
                options: dict[str, Any], keep_frames: bool, env_options: dict[str, Any],
                progress: bool | Callable = False, requested_delays: str | None = None) -> dict[str, Any]:
    """One run as ``doabench run`` does it (journal + lock in ``out``); returns the results dict.
    ``delays``: the mode the run uses (it names the files); ``requested_delays``: what the user
    asked for (None: the tracker's trained mode), so the results record an override.

    Top-level (picklable) so that a Ray worker can run it; the caller writes the results."""
    from doabench.runner import run_lock, run_task
    from doabench.trackers.registry import make_tracker

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    tracker = make_tracker(tracker_id, **options)
    partial = partial_path_for(out, task_id, tracker_id, options, delays)
    with run_lock(partial):
        results = run_task(tracker, task_id, episodes=episodes, delays=requested_delays, tracker_options=options,
                           partial_path=partial, progress=progress, keep_frames=keep_frames, lock=False,
                           **env_options)
    results["tracker"]["id"] = tracker_id
    return results


def _finish(run: SweepRun, results: dict[str, Any], out: Path, options: dict[str, Any], delays: str,
            overwrite: bool = False) -> None:
    from doabench.results.writer import write_results

    json_path, _ = write_results(results, out, overwrite=overwrite)
    partial_path_for(out, run.task, run.tracker, options, delays).unlink(missing_ok=True)
    run.status, run.json_path = "done", json_path
    run.rmsae_all = float(results["summary"]["rmsae_all"])


def sweep(trackers: str | Sequence[str], tasks: str | Sequence[str], out: str | Path,
          episodes: int | None = None, delays: str | None = None, tracker_options: dict[str, Any] | None = None,
          keep_frames: bool = True, engine: str = "local", ray_address: str | None = None,
          workers: int | None = None, leaderboard: str | Path | None = None,
          log: Callable[[str], None] = print, progress: bool = False, overwrite: bool = False,
          **env_options: Any) -> SweepResult:
    """Run every (tracker, task) of the lists into ``out`` and build the leaderboard of ``out``
    (into ``leaderboard``, default ``out/leaderboard``).

    A results file of another configuration in the way (another task version, other weights) is
    replaced only with ``overwrite``; without it that run fails at once, before any work."""
    from doabench.envs.registry import get_task_spec
    from doabench.ray_support import check_engine, require_ray
    from doabench.results.writer import check_overwrite, configuration
    from doabench.trackers.registry import canonical_tracker, make_tracker

    check_engine(engine)
    if engine == "ray":
        require_ray()
    trackers, tasks = parse_list(trackers, "trackers"), parse_list(tasks, "tasks")
    options = dict(tracker_options or {})
    task_ids = [get_task_spec(t).id for t in tasks]  # unknown ids: one line, before any work
    built = {t: make_tracker(t, **options) for t in trackers}
    # One model, one run: aliases (cross3d, cross3d:16x32) resolve to one canonical id and options.
    canonical = {t: canonical_tracker(t, options, tracker) for t, tracker in built.items()}
    opts = {cid: o for cid, o in canonical.values()}
    weights = {canonical[t][0]: tracker.weights_hash() for t, tracker in built.items()}
    versions = {canonical[t][0]: tracker.version for t, tracker in built.items()}
    # each tracker on the observations it was trained on, unless --delays asks for others
    delays_of = {canonical[t][0]: resolve_delays(tracker, delays)[0] for t, tracker in built.items()}
    trackers = list(dict.fromkeys(cid for cid, _ in canonical.values()))
    del built
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    runs = [SweepRun(tracker, task) for task in task_ids for tracker in trackers]
    todo = []
    for run in runs:
        path = finished_results(out, run.task, run.tracker, episodes, delays_of[run.tracker], opts[run.tracker],
                                weights[run.tracker], versions[run.tracker])
        if path is not None:
            run.status, run.json_path = "skipped", path
            log(f"{run.tracker} on {run.task}: already done ({path.name})")
            continue
        try:  # refuse to replace another configuration's file now, not after the run
            spec = get_task_spec(run.task)
            check_overwrite(out / f"{run_stem(run.task, run.tracker, opts[run.tracker], delays_of[run.tracker])}.json",
                            configuration(spec.id, spec.version, run.tracker, opts[run.tracker], weights[run.tracker],
                                          delays_of[run.tracker]), overwrite)
        except DoabenchError as exc:
            run.status, run.error = "failed", str(exc)
            _log_run(run, log)
            continue
        todo.append(run)
    if engine == "local":
        for run in todo:
            t0 = time.perf_counter()
            try:
                results = execute_run(run.tracker, run.task, out, episodes, delays_of[run.tracker], opts[run.tracker],
                                      keep_frames, env_options, progress=progress, requested_delays=delays)
                _finish(run, results, out, opts[run.tracker], delays_of[run.tracker], overwrite)
            except OutputError:
                raise  # a full disk or read-only folder fails every later run too: stop, journals kept
            except DoabenchError as exc:
                run.status, run.error = "failed", str(exc)
            run.seconds = time.perf_counter() - t0
            _log_run(run, log)
    elif todo:
        _sweep_ray(todo, out, (episodes, delays_of, keep_frames, env_options), opts, ray_address, workers, log,
                   overwrite, delays)
    result = SweepResult(out, runs)
    if any(r.status in ("done", "skipped") for r in runs):
        from doabench.results.leaderboard import build_leaderboards, default_references, write_leaderboards

        board = Path(leaderboard) if leaderboard is not None else out / "leaderboard"
        files = build_leaderboards(out, default_references(board),
                                   command=f"doabench leaderboard --results {out} --out {board}")
        write_leaderboards(files, board)
        result.leaderboard, result.leaderboard_files = board, sorted(files)
    return result


def _log_run(run: SweepRun, log: Callable[[str], None]) -> None:
    if run.status == "done":
        log(f"{run.tracker} on {run.task}: RMSAE {run.rmsae_all:.2f} deg ({run.seconds:.1f} s) -> {run.json_path}")
    else:
        log(f"{run.tracker} on {run.task}: failed: {run.error}")


def _sweep_ray(todo: list[SweepRun], out: Path, args: tuple, opts: dict[str, dict[str, Any]], address: str | None,
               workers: int | None, log: Callable[[str], None], overwrite: bool = False,
               requested_delays: str | None = None) -> None:
    """``args``: ``(episodes, delays_of, keep_frames, env_options)`` of every run, ``delays_of``
    the delay mode of each tracker's runs; ``opts``: each tracker's (canonical) options;
    ``requested_delays``: the user's ``--delays`` (None: each tracker's trained mode)."""
    episodes, delays_of, keep_frames, env_options = args
    from doabench.ray_support import ray_session, unwrap

    with ray_session(address, workers or (None if address else min(len(todo), 2))) as ray:
        remote = ray.remote(num_cpus=1)(execute_run)
        # The out folder is passed as an absolute path: on a cluster it must be a shared folder
        # (the workers keep the runs' journals there); the driver writes the results files.
        refs = {remote.remote(run.tracker, run.task, str(out.resolve()), episodes, delays_of[run.tracker],
                              opts[run.tracker], keep_frames, env_options, False, requested_delays): (run, time.perf_counter())
                for run in todo}
        try:
            while refs:
                ready, _ = ray.wait(list(refs), num_returns=1)
                run, t0 = refs.pop(ready[0])
                try:
                    _finish(run, ray.get(ready[0]), out, options=opts[run.tracker], delays=delays_of[run.tracker],
                            overwrite=overwrite)
                except Exception as exc:
                    exc = unwrap(exc)
                    if not isinstance(exc, DoabenchError) or isinstance(exc, OutputError):
                        raise exc
                    run.status, run.error = "failed", str(exc)
                run.seconds = time.perf_counter() - t0
                _log_run(run, log)
        finally:
            for ref in refs:
                ray.cancel(ref)
