"""Every per-episode metric of a run's row: the scored frames' summary, then the lag and the
RMSAE by angular speed of the whole sequence."""
from __future__ import annotations

from typing import Any

import numpy as np

from doabench.geometry import fold_to_upper
from doabench.metrics.motion import motion_metrics
from doabench.metrics.scoring import score_frames


def score_episode(estimates: np.ndarray, truth: np.ndarray, vad: np.ndarray, valid: np.ndarray | None = None,
                  planar: bool = False, times: np.ndarray | None = None) -> dict[str, Any]:
    """Every per-episode metric under the rules of :func:`~doabench.metrics.scoring.score_frames`:
    ``frames_scored``, ``frames_invalid``, :func:`~doabench.metrics.scoring.error_summary`'s
    metrics, then the lag and angular-speed bands (:func:`~doabench.metrics.motion.motion_metrics`, which need the evenly spaced frame ``times`` ``(T,)``; the whole
    sequence is kept for the delayed truth, the voice-active valid frames are scored)."""
    est, tru = np.asarray(estimates, np.float64).reshape(-1, 3), np.asarray(truth, np.float64).reshape(-1, 3)
    if planar:  # folded once for the whole sequence: the lag needs every frame, the scores the valid ones
        est, tru = fold_to_upper(est), fold_to_upper(tru)
    scored = score_frames(est, tru, vad, valid)
    out: dict[str, Any] = {"frames_scored": int(scored.keep.sum()), "frames_invalid": scored.n_invalid,
                           **scored.summary()}
    t = np.asarray(times if times is not None else (), np.float64)
    if len(t) < 2:
        out.update({"lag_s": None, "lag_note": "fewer than two frames: no defined lag"})
        return out
    use = np.asarray(vad, bool) & scored.keep
    out.update(motion_metrics(est, tru, use, float(np.median(np.diff(t)))))
    return out
