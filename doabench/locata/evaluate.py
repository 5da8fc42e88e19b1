"""Score a submission folder in the challenge's format against a LOCATA corpus copy.

Which recordings: for each task (``tasks``, else the submission's ``task<N>`` folders) and array
(``arrays``, else the array folders of that task in the submission), every recording of the corpus
split that has the array (doabench.locata.layout.find_recordings); the submission must hold tracks
for each of them. Every recording is read and checked before any is scored, so bad input stops
the evaluation before anything is written.
"""
from __future__ import annotations

import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

from doabench.errors import InputError
from doabench.locata.layout import ARRAYS, TASKS, check_choice, find_recordings
from doabench.locata.measures import RecordingMeasures, check_mode, recording_measures, task_averages
from doabench.locata.stamps import StampTruth, stamp_truth
from doabench.locata.submission import Tracks, read_tracks, recording_folder

_TASK_RE = re.compile(r"^task(\d+)$")


@dataclass
class ScoredRecording:
    """One recording and array: its truth on the stamps, the submission's tracks and the measures."""

    task: int
    recording: int
    array: str
    truth: StampTruth
    tracks: Tracks
    measures: RecordingMeasures


@dataclass
class Evaluation:
    """The scored recordings (task, array, recording order), the task averages by task and array,
    and the warnings raised while scoring (measures with nothing to average)."""

    mode: str
    split: str
    submission: Path
    root: Path
    recordings: list[ScoredRecording]
    tasks: dict[int, dict[str, dict]] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def submission_tasks(submission: Path) -> list[int]:
    """The LOCATA task numbers with a ``task<N>`` folder in ``submission``."""
    found = [int(m.group(1)) for p in submission.iterdir() if p.is_dir() and (m := _TASK_RE.match(p.name))]
    return sorted(t for t in found if t in TASKS)


def submission_arrays(submission: Path, task: int) -> list[str]:
    """The array names with a folder under any ``task<N>/recording<R>/`` of ``submission``."""
    base = submission / f"task{task}"
    names = {p.name for rec in base.glob("recording*") if rec.is_dir() for p in rec.iterdir() if p.is_dir()}
    return sorted(names & set(ARRAYS))


def _plan(root: str | os.PathLike | None, submission: Path, split: str, tasks: Sequence[int] | None,
          arrays: Sequence[str] | None) -> list[tuple[int, str]]:
    """The (task, array) pairs to score."""
    if not submission.is_dir():
        raise InputError(f"--submission {submission} is not a folder (expected task<N>/recording<R>/<array>/"
                         "source_<k>.txt)")
    chosen = sorted(set(int(t) for t in tasks)) if tasks else submission_tasks(submission)
    if not chosen:
        raise InputError(f"submission {submission} has no task<N> folder (expected task<N>/recording<R>/<array>/"
                         "source_<k>.txt)")
    plan = []
    for task in chosen:
        names = list(arrays) if arrays else submission_arrays(submission, task)
        if not names:
            raise InputError(f"submission has no tracks for task {task}: no {submission}/task{task}/recording<R>/"
                             "<array>/ folder")
        for array in names:
            check_choice(split, task, array)
            plan.append((task, array))
    return plan


def evaluate(root: str | os.PathLike | None, submission: str | os.PathLike, split: str = "dev",
             tasks: Sequence[int] | None = None, arrays: Sequence[str] | None = None,
             mode: str = "official") -> Evaluation:
    """Read every recording's truth and tracks, then score them (see the module docstring)."""
    check_mode(mode)
    folder = Path(submission)
    read: list[tuple[int, str, int, StampTruth, Tracks]] = []
    base = None
    for task, array in _plan(root, folder, split, tasks, arrays):
        for rec in find_recordings(root, split, task, array):
            base = rec.root
            truth = stamp_truth(rec)
            tracks = read_tracks(recording_folder(folder, task, rec.number, array), truth.required_times, truth.origin)
            read.append((task, array, rec.number, truth, tracks))
    evaluation = Evaluation(mode, split, folder, Path(base) if base else Path("."), [])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for task, array, number, truth, tracks in read:
            measures = recording_measures(truth.times, truth.azimuth, truth.inclination, truth.vad,
                                          tracks.azimuth[:, truth.valid], tracks.inclination[:, truth.valid], mode,
                                          truth.sources, label=f"task {task} recording {number} {array}")
            evaluation.recordings.append(ScoredRecording(task, number, array, truth, tracks, measures))
    evaluation.warnings = [str(w.message) for w in caught]
    for task, array in sorted({(r.task, r.array) for r in evaluation.recordings}):
        group = [r for r in evaluation.recordings if (r.task, r.array) == (task, array)]
        averages = task_averages([r.measures for r in group])
        evaluation.tasks.setdefault(task, {})[array] = {"recordings": [r.recording for r in group], **averages}
    return evaluation
