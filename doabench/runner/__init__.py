"""Evaluation: run a tracker on a task and score it (what ``doabench run`` does).

* :mod:`doabench.runner.spec`: one run's identity, :class:`RunSpec` (results file stem, journal,
  configuration) and :func:`run_task`, which the CLI, ``sweep`` and :func:`doabench.run` run through;
* :mod:`doabench.runner.loop`: the episode loop (:func:`track_frames`), the checks of a tracker's
  outputs;
* :mod:`doabench.runner.recordings`: the same tracker calls on a user's recording
  (``doabench track``), in memory or chunk by chunk;
* :mod:`doabench.runner.journal`: the resume journal (``.partial.jsonl``) and the run lock;
* :mod:`doabench.runner.summary`: the results dictionary (schema ``doabench.results/2``).
"""
from doabench.runner.journal import run_lock
from doabench.runner.loop import check_direction, check_directions, check_trained, guarded, step_frame, track_frames
from doabench.runner.spec import RunSpec, run_task

__all__ = ["RunSpec", "check_direction", "check_directions", "check_trained", "guarded", "run_lock", "run_task",
           "step_frame", "track_frames"]
