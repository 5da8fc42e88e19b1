"""One run's identity as a value: :class:`RunSpec`.

A run is a tracker configuration (its canonical id, options and weights) on a task (id and
version, and the run-time options that change its episodes or scoring: a simulator, scene
overrides, a LOCATA split or VAD; :func:`doabench.envs.sources.task_identity`) with the SRP delay
mode its observations use. Everything that names or recognises a run
derives from this one value: the results file stem, the configuration two files are compared by,
the resume journal and its lock, and the hash that heads the journal. ``doabench run``, ``doabench
sweep`` and the Python API (:func:`doabench.run`) all build one and call :meth:`RunSpec.execute`,
so the three agree on every name by construction.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

from doabench.envs.registry import get_task_spec
from doabench.envs.sources import task_identity
from doabench.envs.spec import TaskSpec
from doabench.results.writer import configuration, results_stem
from doabench.runner.journal import run_lock
from doabench.runner.loop import Progress, execute_spec
from doabench.trackers.base import Tracker, resolve_delays
from doabench.trackers.registry import TrackerRef, canonical_ref, make_tracker, tracker_ref


@dataclass(frozen=True)
class RunSpec:
    """``tracker`` is the canonical id (aliases resolved), ``options`` the canonical options,
    ``delays`` the mode the run uses; ``trained_delays`` is set only when that mode is not the one
    the weights were trained on (asked for on purpose), ``given_id`` only when the user typed an
    alias of ``tracker``. ``task_options``: the run-time options of the task that are part of the
    identity (``{}`` on the task's defaults). ``task_spec`` and ``tracker_ref`` are the task and the
    canonical tracker id resolved (by :meth:`build`), carried so that nothing looks them up again,
    in this process or in a worker the spec is sent to; they are not part of the identity."""

    task: str
    task_version: int
    tracker: str
    options: Mapping[str, Any] = field(default_factory=dict)
    weights_hash: str | None = None
    delays: str = "nearest"
    requested_delays: str | None = None
    trained_delays: str | None = None
    given_id: str | None = None
    task_options: Mapping[str, Any] = field(default_factory=dict)
    weights_name: str | None = None
    task_spec: TaskSpec | None = field(default=None, compare=False, repr=False)
    tracker_ref: TrackerRef | None = field(default=None, compare=False, repr=False)

    @classmethod
    def build(cls, tracker: str | TrackerRef | Tracker, task: str | TaskSpec, options: Mapping[str, Any] | None = None,
              delays: str | None = None, instance: Tracker | None = None,
              env_options: Mapping[str, Any] | None = None) -> tuple["RunSpec", Tracker]:
        """The spec of running ``tracker`` (its ``--tracker`` text or :class:`TrackerRef`, or an
        instance) with ``options`` on ``task`` (an id or its spec) with the run-time ``env_options``
        (corpus roots, ``backend``, ``vad``, ...), and the tracker instance (``instance``, or built
        here). ``delays`` None: the mode the tracker was trained on."""
        options = dict(options or {})
        ref: TrackerRef | None = None
        if isinstance(tracker, (str, TrackerRef)):
            ref = tracker_ref(tracker)
            text, instance = ref.text, instance if instance is not None else make_tracker(ref, **options)
        else:  # an instance: its id with the spec it was built with (a plug-in's ``module:Class:32x64``)
            spec_text = getattr(tracker, "spec", None)
            text, instance = (f"{tracker.name}:{spec_text}" if spec_text else tracker.name), tracker
        try:  # aliases name one model (doabench.trackers.registry.canonical_tracker)
            canonical, options = canonical_ref(ref or text, options, instance)
            tracker_id, ref = canonical.text, canonical
        except Exception:  # an instance of an unregistered class keeps its own name
            tracker_id, ref = text, None
        used, trained = resolve_delays(instance, delays)
        spec = get_task_spec(task)
        return cls(task=spec.id, task_version=spec.version, tracker=tracker_id, options=options,
                   weights_hash=instance.weights_hash(), delays=used, requested_delays=delays,
                   trained_delays=trained, given_id=text if text != tracker_id else None,
                   task_options=task_identity(spec, dict(env_options or {})),
                   weights_name=instance.weights_name, task_spec=spec, tracker_ref=ref), instance

    def resolved_task(self) -> TaskSpec:
        """This run's task spec: the one :meth:`build` resolved, else looked up by :attr:`task_ref`."""
        return self.task_spec if self.task_spec is not None else get_task_spec(self.task_ref)

    @property
    def task_ref(self) -> str:
        """The task id that resolves to this run's task version (``doabench/<id>-v<version>``)."""
        return f"doabench/{self.task}-v{self.task_version}"

    @property
    def stem(self) -> str:
        """The results file stem: ``sim-demo__srp-max_16x32``, ``..__1a2b3c4d`` with options,
        ``sim-walk__cross3d_16x32__moving-long`` with shipped weights (:func:`results_stem`)."""
        return results_stem(self.task, self.tracker, self.options, self.delays, self.weights_hash, self.task_options,
                            self.weights_name)

    def configuration(self) -> dict[str, Any]:
        """What makes two results files the same configuration (results.writer.configuration)."""
        return configuration(self.task, self.task_version, self.tracker, self.options, self.weights_hash, self.delays,
                             self.task_options)

    def results_path(self, out: str | Path) -> Path:
        return Path(out) / f"{self.stem}.json"

    def make_tracker(self) -> Tracker:
        """The tracker of this spec, built again from its canonical id and options (what a worker
        process that received only the spec runs)."""
        return make_tracker(self.tracker_ref or self.tracker, **dict(self.options))

    def journal_path(self, out: str | Path) -> Path:
        """The resume journal of this run in ``out`` (locked while the run goes)."""
        return Path(out) / f".{self.stem}.partial.jsonl"

    def journal_config(self, indices: Sequence[int], env_options: Mapping[str, Any]) -> dict[str, Any]:
        """What heads the journal: a journal of another configuration or episode list is not resumed."""
        return {"task": self.task, "task_version": self.task_version, "tracker": self.tracker,
                "options": dict(self.options), "delays": self.delays, "indices": list(indices),
                "weights": self.weights_hash, "env": {k: str(v) for k, v in env_options.items()}}

    def execute(self, tracker: Tracker, out: str | Path | None = None, *, episodes: int | Sequence[int] | None = None,
                cells: Sequence[str] | None = None, device: str | None = None, progress: Progress = True,
                keep_frames: bool = True, **env_options: Any) -> dict[str, Any]:
        """Run it (``tracker``: the instance :meth:`build` returned) and return the results
        dictionary; with ``out``, resumably through :meth:`journal_path`, which is locked so that a
        second process on the same run is refused."""
        if out is None:
            return execute_spec(self, tracker, None, episodes, cells, device, progress, keep_frames, env_options)
        Path(out).mkdir(parents=True, exist_ok=True)
        partial = self.journal_path(out)
        with run_lock(partial):
            return execute_spec(self, tracker, partial, episodes, cells, device, progress, keep_frames, env_options)


def run_task(tracker: Tracker | str, task: str, episodes: int | Sequence[int] | None = None,
             device: str | None = None, delays: str | None = None, tracker_options: Mapping[str, Any] | None = None,
             partial_path: str | Path | None = None, progress: Progress = True,
             keep_frames: bool = True, lock: bool = True, cells: Sequence[str] | None = None,
             **env_options: Any) -> dict[str, Any]:
    """Run ``tracker`` on ``task`` and return the results dictionary (see docs/results-format).

    ``episodes``: a count or explicit indices; default all of the task's episodes. A count on a
    grid task is spread over its cells (:mod:`doabench.envs.selection`), else the first N.
    ``cells``: on a grid task, only these cells (cell task ids). ``delays``: None runs the tracker
    on the SRP delays it was trained on. ``partial_path``: a JSON-lines journal of finished
    episodes for resuming (any path; :meth:`RunSpec.execute` with an ``out`` folder names it),
    removed by the caller once the results are written; locked for the run unless ``lock=False``
    (the caller holds :func:`run_lock` already)."""
    spec, instance = RunSpec.build(tracker, task, tracker_options, delays, env_options=env_options)
    if partial_path is None or not lock:
        return execute_spec(spec, instance, partial_path, episodes, cells, device, progress, keep_frames, env_options)
    with run_lock(partial_path):
        return execute_spec(spec, instance, partial_path, episodes, cells, device, progress, keep_frames, env_options)
