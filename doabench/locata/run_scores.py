"""The LOCATA measures of a ``doabench run`` on a LOCATA task, and its estimates as a submission.

Per episode (:func:`episode_scores`): the tracker's per-frame directions become one track on the
recording's required stamps (doabench.locata.tracks), scored against the truth on the stamps
(doabench.locata.stamps, the corpus VAD) with the challenge's measures in both modes and with
SRP-DNN's protocol. Per run (:func:`summarise`): every recording's values and the task averages,
stored in the results under ``locata``. A recording whose stamps cannot be scored (no corpus VAD
file, no ground truth) is left out with a warning; the run goes on.

:func:`submission_from_results` writes the same tracks in the challenge's submission format from
a results dictionary that kept its per-frame estimates.
"""
from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from doabench.errors import ConfigError, DoabenchError
from doabench.features.spec import ObservationSpec
from doabench.locata.layout import Recording
from doabench.locata.measures import MODES, recording_measures, task_averages
from doabench.locata.report import finite_or_null
from doabench.locata.srpdnn import recording_mean, srp_dnn_scores
from doabench.locata.stamps import stamp_truth
from doabench.locata.tables import read_required_time, read_times
from doabench.locata.tracks import frame_ends, stamp_track, submission_files


def episode_scores(rec: Recording, start_s: float, centres: np.ndarray, directions: np.ndarray, window: int,
                   fs: int) -> dict[str, Any] | None:
    """The measures of one episode: ``centres`` ``(F,)`` its frame centres (seconds from its first
    sample, which lies at ``start_s``), ``directions`` ``(F, 3)`` the tracker's unit vectors (rows
    of NaNs where it said no source: no active track at the stamps that take them).
    None (and a warning) when the recording's stamps cannot be scored."""
    try:
        truth = stamp_truth(rec)
    except DoabenchError as exc:
        warnings.warn(f"LOCATA measures of {rec.id} not computed: {exc}")
        return None
    az, inc = stamp_track(truth.times, frame_ends(start_s, centres, window, fs), directions)
    out: dict[str, Any] = {"task": rec.task, "recording": rec.number, "array": rec.array, "start_s": float(start_s),
                           "sources": list(truth.sources)}
    for mode in MODES:
        out[mode] = recording_measures(truth.times, truth.azimuth, truth.inclination, truth.vad, az[None], inc[None],
                                       mode, truth.sources, label=rec.id).to_json()
    if len(truth.sources) == 1:
        out["srp_dnn"] = srp_dnn_scores(truth.azimuth[0], truth.inclination[0], truth.vad[0], az, inc)
    return out


def summarise(scores: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """The results' ``locata`` block: the recordings' values and, per mode, the task averages
    (one task and array per run); SRP-DNN's protocol averaged over recordings. NaN is None."""
    recordings = list(scores)
    out: dict[str, Any] = {"recordings": recordings}
    for mode in MODES:
        out[mode] = task_averages([r[mode] for r in recordings])
    out["srp_dnn"] = recording_mean([r["srp_dnn"] for r in recordings if "srp_dnn" in r])
    return finite_or_null(out)


def submission_from_results(results: Mapping[str, Any], folder: Path) -> dict[Path, str]:
    """The submission files (path -> text) of a LOCATA run's results: one track per recording
    from its per-frame estimates, ``telapsed.txt`` its tracker time. ConfigError when the results
    kept no per-frame estimates or carry no LOCATA block."""
    source = results["task"]["source"]
    frames, rows = results.get("frames"), results["episodes"]
    scored = {(r["recording"]): r for r in (results.get("locata") or {}).get("recordings", [])}
    if frames is None or any(f is None for f in frames):
        raise ConfigError("--locata-submission needs the per-frame estimates: run without --no-frames")
    frame_spec = ObservationSpec.from_dict(results["observations"]).frame_spec
    window, fs = frame_spec.window, frame_spec.fs
    out: dict[Path, str] = {}
    for row, frame in zip(rows, frames):
        number = int(row["recording"])
        if number not in scored:
            continue  # its stamps could not be scored (a warning said so): no truth-free track either
        rec = Recording(Path(source["root"]), source["split"], int(source["locata_task"]), number, source["array"])
        _, origin = read_times(rec.audio_timestamps_file, "array audio time stamps, one per sample")
        required, _ = read_required_time(rec.required_time_file, origin)
        ends = frame_ends(scored[number]["start_s"], frame["times"], window, fs)
        az, inc = stamp_track(required, ends, np.asarray(frame["estimates"], np.float64))
        out.update(submission_files(folder, rec.task, number, rec.array, rec.required_time_file, az, inc,
                                    float(row["tracker_s"])))
    return out
