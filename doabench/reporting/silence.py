"""Where a run's error is relative to the talker's voice: its per-frame records by voice activity.

A results file written without ``--no-frames`` holds every episode's estimates, truth and VAD.
Scored as ``doabench run`` scores them (:func:`episode_frames`), their errors split by frames
since the last voice-active frame (:data:`SILENCE_BUCKETS`), before and after the first voice:
:func:`silence_metrics` compares two runs by that split (``doabench compare --silence``),
:func:`silence_breakdown` shows one run's, with what holding a direction through the silences
gives (:func:`held_rmsae`, the learned trackers' hold rule, and :func:`hold_the_truth`, an oracle).
The voice-active errors alone are the frame values of the median and 90th percentile
(:func:`voiced_errors`).
"""
from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np

from doabench.metrics import Metric, pooled_rms, rms, rms_from_sums, score_frames, squared_error_sums
from doabench.metrics.pooled import FrameRecords, Rows
from doabench.trackers.hold import hold_in_silences

#: runs of frames since the last voice-active frame, ``[low, high)`` (high None: no bound)
SILENCE_BUCKETS = ((1, 3), (3, 6), (6, 11), (11, 21), (21, 31), (31, 41), (41, None))


def last_voice_index(vad: np.ndarray) -> np.ndarray:
    """``(T,)`` index of the last voice-active frame at or before each frame, -1 before the first."""
    vad = np.asarray(vad, bool)
    return np.maximum.accumulate(np.where(vad, np.arange(len(vad)), -1))


def frames_since_voice(vad: np.ndarray) -> np.ndarray:
    """``(T,)`` frames since the last voice-active frame: 0 on one, -1 before the first."""
    last = last_voice_index(vad)
    return np.where(last >= 0, np.arange(len(last)) - last, -1)


def _unit(a: Any) -> np.ndarray:
    a = np.asarray(a, np.float64).reshape(-1, 3)
    with np.errstate(invalid="ignore", divide="ignore"):
        return a / np.linalg.norm(a, axis=-1, keepdims=True)


def episode_frames(frame: dict[str, Any], hold: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(errors deg, vad, frames since voice)`` of an episode's scored frames, scored as ``doabench
    run`` scores (:func:`doabench.metrics.score_frames`: invalid truth left out, a planar array's
    directions folded), with the estimates held after ``hold`` silent frames when given (the
    learned trackers' rule)."""
    est, truth = _unit(frame["estimates"]), _unit(frame["truth"])
    vad = np.asarray(frame["vad"], bool).reshape(-1)
    if hold is not None:
        est = hold_in_silences(est, vad, hold)
    scored = score_frames(est, truth, vad, frame.get("valid"), bool(frame.get("planar")))
    return scored.errors, scored.vad, frames_since_voice(vad)[scored.keep]


def voiced_errors(frames: Sequence[dict[str, Any]]) -> tuple[np.ndarray, np.ndarray]:
    """Errors of the voice-active frames and the position of each one's episode."""
    errs, owner = [], []
    for i, f in enumerate(frames):
        e, vad, _ = episode_frames(f)
        errs.append(e[vad])
        owner.append(np.full(int(vad.sum()), i))
    return (np.concatenate(errs) if errs else np.zeros(0)), (np.concatenate(owner) if owner else np.zeros(0, int))


def _since_voice_between(lo: int, hi: int | None) -> Callable[[np.ndarray], np.ndarray]:
    """Selects the frames ``lo`` to ``hi - 1`` since the last voice-active frame (``lo`` and more when
    ``hi`` is None), from the frames since voice of each frame."""
    return lambda since: (since >= lo) & ((since < hi) if hi else True)


def _frame_rms_stats(select: Callable[[np.ndarray], np.ndarray],
                     hold: int | None = None) -> Callable[[Rows, FrameRecords], np.ndarray]:
    """Per episode, the summed squared errors and the count of the frames ``select`` picks by their
    frames since voice (:class:`doabench.metrics.Metric` sums of a pooled RMS)."""
    def stats(rows: Rows, frames: FrameRecords) -> np.ndarray:
        assert frames is not None
        picked = []
        for f in frames:
            e, _, since = episode_frames(f, hold)
            picked.append(e[select(since)])
        return np.stack(squared_error_sums(picked), 1)
    return stats


def silence_metrics(holds: Sequence[int] = ()) -> list[Metric]:
    """RMSAE by frames since the last voice-active frame, before and after the first voice, and
    with the estimates held after each of ``holds`` silent frames (all need per-frame estimates)."""
    out = []
    for lo, hi in SILENCE_BUCKETS:
        name = f"{lo}-{hi - 1}" if hi else f"{lo}+"
        out.append(Metric(f"rmsae_since_voice_{name}", f"RMSAE {name} frames after voice", "deg", False,
                          _frame_rms_stats(_since_voice_between(lo, hi)), pooled_rms))
    out += [Metric("rmsae_before_first_voice", "RMSAE before the first voice", "deg", False,
                   _frame_rms_stats(lambda since: since < 0), pooled_rms),
            Metric("rmsae_after_first_voice", "RMSAE after the first voice", "deg", False,
                   _frame_rms_stats(lambda since: since >= 0), pooled_rms)]
    for hold in holds:
        out.append(Metric(f"rmsae_all_hold_{hold}", f"RMSAE all frames, held after {hold} silent frames", "deg",
                          False, _frame_rms_stats(lambda since: np.ones(len(since), bool), hold), pooled_rms))
    return out


def silence_breakdown(frames: Sequence[dict[str, Any]]) -> list[tuple[str, int, float, float]]:
    """``(rows label, frames, RMSAE deg, share of the squared error)`` by frames since the last
    voice-active frame, then before and after the first voice."""
    parts = [episode_frames(f) for f in frames]
    e = np.concatenate([x[0] for x in parts]) if parts else np.zeros(0)
    since = np.concatenate([x[2] for x in parts]) if parts else np.zeros(0, int)
    total = float(np.square(e).sum())
    groups = [("0 (voice-active)", since == 0)]
    groups += [(f"{lo}-{hi - 1}" if hi else f"{lo} and more", _since_voice_between(lo, hi)(since))
               for lo, hi in SILENCE_BUCKETS]
    groups += [("before the first voice", since < 0), ("after the first voice (all but the row above)", since >= 0)]
    out = []
    for label, m in groups:
        sq = float(np.square(e[m]).sum())
        out.append((label, int(m.sum()), float(rms_from_sums(sq, m.sum())), sq / total if total else float("nan")))
    return out


def held_rmsae(frames: Sequence[dict[str, Any]], hold: int) -> float:
    """RMSAE over all frames of the estimates held after ``hold`` silent frames (the learned
    trackers' rule, ``doabench.hold_in_silences``)."""
    errors = [episode_frames(f, hold)[0] for f in frames]
    return rms(np.concatenate(errors) if errors else np.zeros(0))


def hold_the_truth(frames: Sequence[dict[str, Any]]) -> float:
    """RMSAE over all frames of an oracle that knows the true direction of every voice-active
    frame and holds the last one through silent frames (90° before the first voice-active frame),
    scored as the runs are: what any tracker that holds its last direction can reach on these
    episodes."""
    sq, n = 0.0, 0
    for f in frames:
        truth = _unit(f["truth"])
        vad = np.asarray(f["vad"], bool).reshape(-1)
        last = last_voice_index(vad)
        scored = score_frames(truth[np.maximum(last, 0)], truth, vad, f.get("valid"), bool(f.get("planar")))
        err = np.where((last < 0)[scored.keep], 90.0, scored.errors)
        sq += float(np.square(err).sum())
        n += err.size
    return float(rms_from_sums(sq, n))
