"""Frame errors and the one scoring rule: which frames of an episode are scored, and how.

The definitions (great-circle and azimuth errors, the summary metrics, "no source" frames, the
pooled and episode-mean aggregates) are those of :mod:`doabench.metrics`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from doabench.geometry import (NO_SOURCE_ERROR_DEG, fold_to_upper, great_circle_error, is_no_source, unit_to_angles,
                               wrap_angle)

THRESHOLDS_DEG = (5, 10, 20, 30)


def _no_estimate_scored(errors: np.ndarray, estimates: np.ndarray) -> np.ndarray:
    """``errors`` with the frames whose estimate says "no source" at ``NO_SOURCE_ERROR_DEG``."""
    none = is_no_source(estimates)
    return np.where(none, NO_SOURCE_ERROR_DEG, errors) if none.any() else errors


def frame_errors_deg(estimates: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Great-circle errors in degrees, ``(T, 3), (T, 3) -> (T,)``; a "no source" estimate (three
    NaNs) counts ``NO_SOURCE_ERROR_DEG``."""
    est = np.asarray(estimates, np.float64)
    return _no_estimate_scored(np.degrees(great_circle_error(est, np.asarray(truth, np.float64))), est)


def azimuth_errors_deg(estimates: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Absolute wrapped azimuth errors in degrees, ``(T, 3), (T, 3) -> (T,)``; a "no source"
    estimate counts ``NO_SOURCE_ERROR_DEG``."""
    est = np.asarray(estimates, np.float64)
    _, az_e = unit_to_angles(est)
    _, az_t = unit_to_angles(np.asarray(truth, np.float64))
    return _no_estimate_scored(np.degrees(np.abs(wrap_angle(az_e - az_t))), est)


def rms(errors: np.ndarray) -> float:
    """The RMS of ``errors``; NaN for none."""
    return float(np.sqrt(np.mean(np.square(errors)))) if errors.size else float("nan")


def rms_from_sums(sum_sq: Any, n: Any) -> np.ndarray:
    """The RMS of ``n`` frames whose squared errors sum to ``sum_sq``, elementwise (a pooled RMS is
    ``sqrt(sum_i n_i rms_i^2 / sum_i n_i)``); NaN where there are no frames."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(np.asarray(sum_sq, np.float64) / np.asarray(n, np.float64))


def squared_error_sums(errors: Iterable[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per episode of ``errors`` (one array of frame errors each), the summed squared errors and
    the frame count: ``(sum_sq (E,), n (E,))``, the sums every pooled RMS and its bootstrap start from."""
    parts = [np.asarray(e, np.float64) for e in errors]
    return (np.array([np.sum(np.square(e)) for e in parts], np.float64),
            np.array([e.size for e in parts], np.float64))


def _stat(fn: Callable[[np.ndarray], Any], x: np.ndarray) -> float:
    return float(fn(x)) if x.size else float("nan")


def error_summary(errors: np.ndarray, vad: np.ndarray, az_errors: np.ndarray | None = None) -> dict[str, float]:
    """All metrics from per-frame errors (degrees) and the frame VAD (bool)."""
    errors = np.asarray(errors, np.float64)
    vad = np.asarray(vad, bool)
    active = errors[vad]
    out = {
        "rmsae_all": rms(errors),
        "rmsae_nonsilent": rms(active),
        "mae_all": _stat(np.mean, errors),
        "mae": _stat(np.mean, active),
        "median": _stat(np.median, active),
        "p90": _stat(lambda a: np.percentile(a, 90), active),
    }
    for th in THRESHOLDS_DEG:
        out[f"within_{th}"] = _stat(lambda a: np.mean(a <= th), active)
    if az_errors is not None:
        out["azimuth_mae"] = _stat(np.mean, np.asarray(az_errors, np.float64)[vad])
    out["n_frames"] = int(errors.size)
    out["n_nonsilent"] = int(vad.sum())
    return out


def episode_metrics(estimates: np.ndarray, truth: np.ndarray, vad: np.ndarray) -> dict[str, float]:
    """Metrics of one episode from ``estimates (T, 3)``, ``truth (T, 3)``, ``vad (T,)``."""
    return error_summary(frame_errors_deg(estimates, truth), vad, azimuth_errors_deg(estimates, truth))


@dataclass(frozen=True)
class ScoredFrames:
    """An episode's frames as every score sees them (:func:`score_frames`)."""

    #: ``(T,)`` bool: which of the episode's frames are scored (truth valid)
    keep: np.ndarray
    #: ``(n, 3)`` estimates and truth of the scored frames, mirror-folded for a planar array
    estimates: np.ndarray
    truth: np.ndarray
    #: ``(n,)`` bool voice activity of the scored frames
    vad: np.ndarray
    #: ``(n,)`` great-circle and wrapped azimuth errors in degrees
    errors: np.ndarray
    az_errors: np.ndarray

    @property
    def n_invalid(self) -> int:
        """Frames left out because their truth is invalid."""
        return int(self.keep.size - self.keep.sum())

    def summary(self) -> dict[str, float]:
        """:func:`error_summary` of the scored frames (RMSAE all / non-silent, MAE, ...)."""
        return error_summary(self.errors, self.vad, self.az_errors)


def score_frames(estimates: np.ndarray, truth: np.ndarray, vad: np.ndarray, valid: np.ndarray | None = None,
                 planar: bool = False) -> ScoredFrames:
    """The scored frames of one episode: ``estimates``, ``truth`` ``(T, 3)``, ``vad`` ``(T,)``,
    ``valid`` ``(T,)`` (None: every frame's truth is valid), ``planar``: the array is planar.

    Frames with invalid truth are left out; for a planar array estimate and truth are folded onto
    the upper half-space (:mod:`doabench.metrics`). The one scoring rule of doabench."""
    est = np.asarray(estimates, np.float64).reshape(-1, 3)
    tru = np.asarray(truth, np.float64).reshape(-1, 3)
    active = np.asarray(vad, bool).reshape(-1)
    if not (len(est) == len(tru) == len(active)):
        raise ValueError(f"score_frames: {len(est)} estimates, {len(tru)} truth rows and {len(active)} vad values")
    keep = np.ones(len(active), bool) if valid is None else np.asarray(valid, bool).reshape(-1)
    est, tru, active = est[keep], tru[keep], active[keep]
    if planar:
        est, tru = fold_to_upper(est), fold_to_upper(tru)
    return ScoredFrames(keep, est, tru, active, frame_errors_deg(est, tru), azimuth_errors_deg(est, tru))


def aggregate(per_frame: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]],
              per_episode: Sequence[dict[str, float]]) -> dict[str, dict[str, float]]:
    """Combine episodes: ``per_frame`` holds (errors_deg, az_errors_deg, vad) per episode.

    Returns ``{"pooled": {...}, "episode_mean": {...}}``.
    """
    if per_frame:
        errs = np.concatenate([p[0] for p in per_frame])
        azs = np.concatenate([p[1] for p in per_frame])
        vad = np.concatenate([p[2] for p in per_frame])
    else:
        errs = azs = np.zeros(0)
        vad = np.zeros(0, bool)
    pooled = error_summary(errs, vad, azs)
    keys = [k for k in pooled if not k.startswith("n_")]
    mean = {k: _nanmean([e.get(k, np.nan) for e in per_episode]) for k in keys}
    mean["n_episodes"] = len(per_episode)
    pooled["n_episodes"] = len(per_episode)
    return {"pooled": pooled, "episode_mean": mean}


def _nanmean(values: list[float]) -> float:
    v = np.asarray(values, np.float64)
    return float(np.mean(v[~np.isnan(v)])) if np.any(~np.isnan(v)) else float("nan")

