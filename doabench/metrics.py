"""Localisation and tracking metrics.

Definitions (all angles reported in degrees):

* frame error ``e_t``: great-circle angle between estimate and truth, ``atan2(|u x v|, u . v)``;
* ``rmsae_all`` = sqrt(mean_t e_t^2) over all frames; ``rmsae_nonsilent`` over voice-active frames
  only (the paper's two numbers: Fig. 6 excludes silent frames, Fig. 8 and Table II include them);
* ``mae``, ``median``, ``p90``: mean, median and 90th percentile of ``e_t`` (non-silent frames);
* ``within_5`` ... ``within_30``: share of non-silent frames with ``e_t`` at most 5/10/20/30 degrees;
* ``azimuth_mae``: mean wrapped azimuth error ``|wrap(az_est - az_true)|`` over voice-active frames,
  the LOCATA challenge's azimuth metric.

Aggregation over episodes comes in two labelled flavours: ``pooled`` (all frames of all episodes
in one pool, the paper's way) and ``episode_mean`` (the mean of per-episode values).
"""
from __future__ import annotations

from typing import Iterable, Sequence

import numpy as np

from doabench.geometry import great_circle_error, unit_to_angles, wrap_angle

THRESHOLDS_DEG = (5, 10, 20, 30)


def frame_errors_deg(estimates: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Great-circle errors in degrees, ``(T, 3), (T, 3) -> (T,)``."""
    return np.degrees(great_circle_error(np.asarray(estimates, np.float64), np.asarray(truth, np.float64)))


def azimuth_errors_deg(estimates: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Absolute wrapped azimuth errors in degrees, ``(T, 3), (T, 3) -> (T,)``."""
    _, az_e = unit_to_angles(np.asarray(estimates, np.float64))
    _, az_t = unit_to_angles(np.asarray(truth, np.float64))
    return np.degrees(np.abs(wrap_angle(az_e - az_t)))


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if x.size else float("nan")


def _stat(fn, x: np.ndarray) -> float:
    return float(fn(x)) if x.size else float("nan")


def error_summary(errors: np.ndarray, vad: np.ndarray, az_errors: np.ndarray | None = None) -> dict[str, float]:
    """All metrics from per-frame errors (degrees) and the frame VAD (bool)."""
    errors = np.asarray(errors, np.float64)
    vad = np.asarray(vad, bool)
    active = errors[vad]
    out = {
        "rmsae_all": _rms(errors),
        "rmsae_nonsilent": _rms(active),
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


def bootstrap_ci(per_frame: Sequence[tuple[np.ndarray, np.ndarray]], statistic: str = "rmsae_nonsilent",
                 n_boot: int = 1000, level: float = 0.95, seed: int = 0) -> tuple[float, float]:
    """Bootstrap confidence interval over episodes (resampled with replacement) of a pooled RMSAE.

    ``per_frame`` holds ``(errors_deg, vad)`` per episode; ``statistic`` is ``rmsae_all`` or
    ``rmsae_nonsilent``. Vectorised: per-episode sums of squares and counts are resampled.
    """
    if not per_frame:
        return float("nan"), float("nan")
    if statistic == "rmsae_all":
        sq = np.array([np.sum(np.square(e)) for e, _ in per_frame])
        n = np.array([e.size for e, _ in per_frame], float)
    elif statistic == "rmsae_nonsilent":
        sq = np.array([np.sum(np.square(e[np.asarray(v, bool)])) for e, v in per_frame])
        n = np.array([np.sum(v) for _, v in per_frame], float)
    else:
        raise ValueError(f"bootstrap_ci supports rmsae_all and rmsae_nonsilent, not {statistic!r}")
    return bootstrap_ci_from_sums(sq, n, n_boot, level, seed)


def bootstrap_ci_from_sums(sum_sq: np.ndarray, counts: np.ndarray, n_boot: int = 1000, level: float = 0.95,
                           seed: int = 0) -> tuple[float, float]:
    """Bootstrap CI of a pooled RMS from per-episode sums of squared errors and frame counts."""
    sq, n = np.asarray(sum_sq, float), np.asarray(counts, float)
    if sq.size == 0:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, sq.size, size=(n_boot, sq.size))
    with np.errstate(invalid="ignore", divide="ignore"):
        values = np.sqrt(sq[idx].sum(1) / n[idx].sum(1))
    if np.all(np.isnan(values)):
        return float("nan"), float("nan")
    lo, hi = np.nanpercentile(values, [(1 - level) / 2 * 100, (1 + level) / 2 * 100])
    return float(lo), float(hi)


def paired_difference_ci(sum_sq_a: np.ndarray, counts_a: np.ndarray, sum_sq_b: np.ndarray, counts_b: np.ndarray,
                         n_boot: int = 1000, level: float = 0.95, seed: int = 0) -> tuple[float, float, float]:
    """The difference of two trackers' pooled RMS errors on the same episodes, ``a - b``, and its
    paired bootstrap interval: each resample draws the same episodes for both (shapes
    ``(episodes,)``, episode ``i`` of ``a`` is episode ``i`` of ``b``), so what the two runs share
    (a hard episode is hard for both) cancels, and the interval is narrower than the two
    trackers' own intervals suggest. Returns ``(difference, low, high)``."""
    sq_a, n_a, sq_b, n_b = (np.asarray(x, float) for x in (sum_sq_a, counts_a, sum_sq_b, counts_b))
    if not (sq_a.shape == n_a.shape == sq_b.shape == n_b.shape) or sq_a.size == 0:
        raise ValueError("paired_difference_ci needs the same, non-empty set of episodes for both trackers")
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, sq_a.size, size=(n_boot, sq_a.size))
    with np.errstate(invalid="ignore", divide="ignore"):
        diffs = np.sqrt(sq_a[idx].sum(1) / n_a[idx].sum(1)) - np.sqrt(sq_b[idx].sum(1) / n_b[idx].sum(1))
    lo, hi = np.nanpercentile(diffs, [(1 - level) / 2 * 100, (1 + level) / 2 * 100])
    return float(np.sqrt(sq_a.sum() / n_a.sum()) - np.sqrt(sq_b.sum() / n_b.sum())), float(lo), float(hi)


def pooled_from_rows(rows: Sequence[dict]) -> dict[str, float]:
    """Pooled RMSAEs (all / non-silent) and their bootstrap CIs from per-episode rows alone.

    Exact: a pooled RMS is sqrt(sum_i n_i rms_i^2 / sum_i n_i) over episodes i.
    """
    out: dict[str, float] = {}
    for stat, count in (("rmsae_all", "n_frames"), ("rmsae_nonsilent", "n_nonsilent")):
        rms = np.array([r[stat] for r in rows], float)
        n = np.array([r[count] for r in rows], float)
        sq = np.where(n > 0, np.nan_to_num(rms) ** 2 * n, 0.0)
        out[stat] = float(np.sqrt(sq.sum() / n.sum())) if n.sum() > 0 else float("nan")
        out[f"{stat}_ci95"] = bootstrap_ci_from_sums(sq, n)
    out["n_episodes"] = len(rows)
    return out


def group_by(rows: Iterable[dict], keys: Sequence[str]) -> dict[tuple, list[dict]]:
    """Group per-episode rows by metadata keys (e.g. ``("t60", "snr")`` for grid cells)."""
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault(tuple(row.get(k) for k in keys), []).append(row)
    return groups
