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

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

from doabench.errors import ConfigError, DoabenchError, OutputError
from doabench.runner.spec import RunSpec


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


def finished_results(out: Path, spec: RunSpec, episodes: int | None, tracker_version: str | None = None) -> Path | None:
    """The results file of a finished run of ``spec`` in ``out``, else None (the run is (re)done):
    the same configuration (task and version, tracker, options, weights, delays), as many episodes,
    and the same ``tracker_version`` (``Tracker.version``) when one is given."""
    from doabench.results.schema import load_results
    from doabench.results.writer import results_configuration

    path = spec.results_path(out)
    if not path.is_file() or spec.journal_path(out).exists():
        return None
    try:
        r = load_results(path)  # a file of an older schema read as the current one
        total = int(r["task"]["episodes_total"])
        want = total if episodes is None else min(int(episodes), total)
        same = (results_configuration(r) == spec.configuration() and int(r["task"]["episodes_run"]) == want
                and (tracker_version is None or str(r["tracker"].get("version")) == str(tracker_version)))
    except (OSError, ValueError, KeyError, TypeError, DoabenchError):
        return None
    return path if same else None


def execute_run(spec: RunSpec, out: str | Path, episodes: int | None, keep_frames: bool, env_options: dict[str, Any],
                progress: bool | Callable = False) -> dict[str, Any]:
    """One run as ``doabench run`` does it (journal + lock in ``out``); returns the results dict.

    Top-level (picklable, and so is the spec) so that a Ray worker can run it; the caller writes
    the results."""
    return spec.execute(spec.make_tracker(), out, episodes=episodes, progress=progress, keep_frames=keep_frames,
                        **env_options)


def _finish(run: SweepRun, results: dict[str, Any], out: Path, spec: RunSpec, overwrite: bool = False) -> None:
    from doabench.results.writer import write_results

    json_path, _ = write_results(results, out, overwrite=overwrite)
    spec.journal_path(out).unlink(missing_ok=True)
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

    A results file in the way that holds another configuration (another task version, other
    weights) or episodes the run does not take (4 of them, then ``episodes=2``) is replaced only
    with ``overwrite`` (``--replace``); without it that run fails at once, before any work."""
    from doabench.envs.registry import get_task_spec, task_reference
    from doabench.ray_support import check_engine, require_ray
    from doabench.results.writer import check_overwrite
    from doabench.envs.selection import select_episodes
    from doabench.trackers.registry import make_tracker, tracker_ref

    check_engine(engine)
    if engine == "ray":
        require_ray()
    trackers, tasks = parse_list(trackers, "trackers"), parse_list(tasks, "tasks")
    options = dict(tracker_options or {})
    # Each id is looked up once, here (unknown ids: one line, before any work); the values go on.
    task_specs = {task_reference(spec): spec for spec in map(get_task_spec, tasks)}
    refs = [tracker_ref(text) for text in trackers]
    # One model, one run: aliases (cross3d, cross3d:16x32) resolve to one canonical id and options
    # (RunSpec.build), each on the observations it was trained on unless --delays asks for others.
    specs: dict[tuple[str, str], RunSpec] = {}
    versions: dict[str, str] = {}
    order: list[str] = []
    for ref in refs:
        instance = make_tracker(ref, **options)
        for task_id, task_spec in task_specs.items():
            spec, _ = RunSpec.build(ref, task_spec, options, delays, instance=instance, env_options=env_options)
            specs.setdefault((spec.tracker, task_id), spec)
        versions[spec.tracker] = instance.version
        order.append(spec.tracker)
    trackers = list(dict.fromkeys(order))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    runs = [SweepRun(tracker, task) for task in task_specs for tracker in trackers]
    todo = []
    for run in runs:
        spec = specs[(run.tracker, run.task)]
        path = finished_results(out, spec, episodes, versions[run.tracker])
        if path is not None:
            run.status, run.json_path = "skipped", path
            log(f"{run.tracker} on {run.task}: already done ({path.name})")
            continue
        try:  # refuse to replace another configuration's file, or drop its episodes, now, not after the run
            task = spec.resolved_task()
            def taken(total: int, task: Any = task) -> Any:  # the episodes this run takes of a task of `total`
                return select_episodes(task, total, episodes)[0]

            check_overwrite(spec.results_path(out), spec.configuration(), overwrite, episodes=taken)
        except DoabenchError as exc:
            run.status, run.error = "failed", str(exc)
            _log_run(run, log)
            continue
        todo.append(run)
    if engine == "local":
        for run in todo:
            spec = specs[(run.tracker, run.task)]
            t0 = time.perf_counter()
            try:
                results = execute_run(spec, out, episodes, keep_frames, env_options, progress=progress)
                _finish(run, results, out, spec, overwrite)
            except OutputError:
                raise  # a full disk or read-only folder fails every later run too: stop, journals kept
            except DoabenchError as exc:
                run.status, run.error = "failed", str(exc)
            run.seconds = time.perf_counter() - t0
            _log_run(run, log)
    elif todo:
        _sweep_ray(todo, out, specs, (episodes, keep_frames, env_options), ray_address, workers, log, overwrite)
    result = SweepResult(out, runs)
    if any(r.status in ("done", "skipped") for r in runs):
        from doabench.reporting.leaderboard import build_leaderboards, default_references, write_leaderboards

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


def _sweep_ray(todo: list[SweepRun], out: Path, specs: dict[tuple[str, str], RunSpec], args: tuple,
               address: str | None, workers: int | None, log: Callable[[str], None], overwrite: bool = False) -> None:
    """``specs``: each run's :class:`RunSpec` by (tracker, task); ``args``: ``(episodes,
    keep_frames, env_options)`` of every run."""
    episodes, keep_frames, env_options = args
    from doabench.ray_support import ray_session, unwrap

    with ray_session(address, workers or (None if address else min(len(todo), 2))) as ray:
        remote = ray.remote(num_cpus=1)(execute_run)
        # The out folder is passed as an absolute path: on a cluster it must be a shared folder
        # (the workers keep the runs' journals there); the driver writes the results files.
        refs = {remote.remote(specs[(run.tracker, run.task)], str(out.resolve()), episodes, keep_frames,
                              env_options): (run, time.perf_counter())
                for run in todo}
        try:
            while refs:
                ready, _ = ray.wait(list(refs), num_returns=1)
                run, t0 = refs.pop(ready[0])
                try:
                    _finish(run, ray.get(ready[0]), out, specs[(run.tracker, run.task)], overwrite=overwrite)
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
