"""Statistics pooled over episodes from their per-episode sums, exactly as over their frames.

Every pooled statistic of a set of episodes is a function of sums the episodes' rows hold: a pooled
RMS is ``sqrt(sum_i n_i rms_i^2 / sum_i n_i)``, a mean over voice-active frames weights each
episode by its voice-active frames, the pooled lag minimises the summed lag curves
(:func:`doabench.metrics.motion.lag_from_curves`), a speed band's RMSAE pools its summed squared
errors. A :class:`Metric` names such a statistic by its per-episode sums and the value of summed
sums, so that a resample of episodes (:mod:`doabench.metrics.bootstrap`) is a matrix product of
draw counts and sums; the frame quantiles (median, p90) are no function of sums and are computed
from the episodes' frames instead (:mod:`doabench.metrics.paired`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from doabench.metrics.bootstrap import bootstrap_ci_from_sums
from doabench.metrics.motion import LAG_MAX_S, LAG_STEP_S, SPEED_BANDS, follows, lag_grid, moves
from doabench.metrics.scoring import THRESHOLDS_DEG, rms_from_sums

#: per-episode rows of a results file (``episodes``)
Rows = Sequence[dict[str, Any]]
#: per-episode frame records of a results file (``frames``: estimates, truth, vad, valid), or None without them
FrameRecords = Sequence[dict[str, Any]] | None
#: the frame values of a set of episodes and the position of each one's episode: ``(values (F,), owner (F,))``
FrameSamples = Callable[[Sequence[dict[str, Any]]], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class Metric:
    """A pooled statistic: ``stats(rows, frames) -> (episodes, k)`` per-episode sums, and
    ``value(sums (B, k)) -> (B,)`` the statistic of episodes whose sums were added up. The last
    column of the sums is positive exactly for the episodes that contribute (their frame count).

    A frame quantile (``quantile`` set) is no function of sums: its value is the quantile of the
    frame values ``samples(frames)`` gives, its one column of sums counts each episode's frames."""

    key: str
    label: str
    unit: str
    higher_is_better: bool
    stats: Callable[[Rows, FrameRecords], np.ndarray]
    value: Callable[[np.ndarray], np.ndarray]
    scale: float = 1.0  # shown value = scale * value (fractions as %)
    quantile: float | None = None
    samples: FrameSamples | None = None


def _num(row: dict[str, Any], key: str) -> float:
    v = row.get(key)
    return float("nan") if v is None else float(v)


def row_sums(rows: Rows, key: str, count: str | None, squared: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Per row, ``value * n`` (``value ** 2 * n`` when ``squared``: an RMS) and ``n``, the row's
    ``count`` (1 per row without one): the sums a frame-weighted pooled mean or RMS adds up. A row
    without a finite value or without frames contributes zeros to both."""
    v = np.array([_num(r, key) for r in rows])
    n = np.ones(len(rows)) if count is None else np.array([_num(r, count) for r in rows])
    ok = np.isfinite(v) & np.isfinite(n) & (n > 0)
    weighted = (np.nan_to_num(v) ** 2 if squared else np.nan_to_num(v)) * np.nan_to_num(n)
    return np.where(ok, weighted, 0.0), np.where(ok, n, 0.0)


def pooled_rms(sums: np.ndarray) -> np.ndarray:
    """The pooled RMS of summed ``[sum of squares, count]`` rows ``(B, 2)``."""
    return rms_from_sums(sums[:, 0], sums[:, 1])


def _ratio(sums: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return sums[:, 0] / sums[:, 1]


def _rms_stats(key: str, count: str) -> Callable[[Rows, FrameRecords], np.ndarray]:
    def stats(rows: Rows, frames: FrameRecords = None) -> np.ndarray:
        return np.stack(row_sums(rows, key, count, squared=True), 1)
    return stats


def _mean_stats(key: str, count: str | None) -> Callable[[Rows, FrameRecords], np.ndarray]:
    def stats(rows: Rows, frames: FrameRecords = None) -> np.ndarray:
        return np.stack(row_sums(rows, key, count), 1)
    return stats


def _count_stats(count: str) -> Callable[[Rows, FrameRecords], np.ndarray]:
    """Frame quantiles are no function of sums: their one column counts each episode's frames."""
    def stats(rows: Rows, frames: FrameRecords = None) -> np.ndarray:
        return np.nan_to_num(np.array([_num(r, count) for r in rows])).reshape(-1, 1)
    return stats


def _lag_stats(rows: Rows, frames: FrameRecords = None) -> np.ndarray:
    """Per episode where its truth moves: its lag curve (summed squared error per delay), the best
    constant direction's error (``lag_const_sse``), 1 where that was not recorded (older files),
    and in the last column 1 (the pooled lag needs a moving episode); zeros where it does not move."""
    d = len(lag_grid(LAG_MAX_S, LAG_STEP_S))
    out = np.zeros((len(rows), d + 3))
    for i, r in enumerate(rows):
        curve, const = r.get("lag_sse"), r.get("lag_const_sse")
        if curve is not None and len(curve) == d and moves(r):
            out[i, :d] = curve
            out[i, d:] = (0.0, 1.0, 1.0) if const is None else (const, 0.0, 1.0)
    return out


def _lag_value(sums: np.ndarray) -> np.ndarray:
    """The pooled lag of the summed curves, NaN where no episode moves or the estimates do not
    follow the talker (:func:`doabench.metrics.motion.follows`), as
    :func:`doabench.metrics.motion.lag_from_curves` decides."""
    curve, const, unrecorded, moving = sums[:, :-3], sums[:, -3], sums[:, -2], sums[:, -1]
    lag = lag_grid(LAG_MAX_S, LAG_STEP_S)[np.argmin(curve, axis=1)]
    return np.where((moving > 0) & follows(curve, np.where(unrecorded > 0, np.nan, const)), lag, np.nan)


def _band_stats(label: str) -> Callable[[Rows, FrameRecords], np.ndarray]:
    def stats(rows: Rows, frames: FrameRecords = None) -> np.ndarray:
        sums = [(r.get("speed_bands") or {}).get(label) or [0.0, 0] for r in rows]
        return np.array([[float(s), float(n)] for s, n in sums]).reshape(-1, 2)
    return stats


def _has(rows: Rows, key: str) -> bool:
    return any(r.get(key) is not None for r in rows)


def summary_metrics(rows_a: Rows, rows_b: Rows, recordings: bool,
                    voiced_errors: FrameSamples | None = None) -> list[Metric]:
    """The metrics both sets of rows carry: RMSAE all frames and voice-active, the mean of the
    recordings' RMSAE (``recordings``), the other summary metrics of the leaderboards, the lag and
    the RMSAE per angular-speed band where present; median and 90th percentile of the voice-active
    errors where ``voiced_errors`` gives them from the episodes' frame records."""
    out = [Metric("rmsae_all", "RMSAE all frames", "deg", False, _rms_stats("rmsae_all", "n_frames"), pooled_rms),
           Metric("rmsae_nonsilent", "RMSAE voice-active frames", "deg", False,
                  _rms_stats("rmsae_nonsilent", "n_nonsilent"), pooled_rms)]
    if recordings:
        out.append(Metric("rmsae_all_recording_mean", "RMSAE all frames, mean of recordings", "deg", False,
                          _mean_stats("rmsae_all", None), _ratio))
    if all(_has(r, "mae") for r in (rows_a, rows_b)):
        out.append(Metric("mae", "MAE voice-active", "deg", False, _mean_stats("mae", "n_nonsilent"), _ratio))
    if voiced_errors is not None:
        out += [Metric("median", "median error voice-active", "deg", False, _count_stats("n_nonsilent"),
                       _ratio, quantile=0.5, samples=voiced_errors),
                Metric("p90", "90th percentile voice-active", "deg", False, _count_stats("n_nonsilent"),
                       _ratio, quantile=0.9, samples=voiced_errors)]
    for th in THRESHOLDS_DEG:
        if all(_has(r, f"within_{th}") for r in (rows_a, rows_b)):
            out.append(Metric(f"within_{th}", f"share within {th}° voice-active", "%", True,
                              _mean_stats(f"within_{th}", "n_nonsilent"), _ratio, scale=100.0))
    if all(_has(r, "azimuth_mae") for r in (rows_a, rows_b)):
        out.append(Metric("azimuth_mae", "azimuth MAE voice-active", "deg", False,
                          _mean_stats("azimuth_mae", "n_nonsilent"), _ratio))
    if all(any(x.get("lag_sse") is not None for x in r) for r in (rows_a, rows_b)):
        out.append(Metric("lag_s", "tracking lag", "s", False, _lag_stats, _lag_value))
    if all(any("speed_bands" in x for x in r) for r in (rows_a, rows_b)):
        for label, _, _ in SPEED_BANDS:
            out.append(Metric(f"rmsae_speed_{label}", f"RMSAE voice-active, truth moving {label} deg/s", "deg",
                              False, _band_stats(label), pooled_rms))
    return out


def pooled_from_rows(rows: Rows) -> dict[str, float | tuple[float, float] | None]:
    """Pooled RMSAEs (all / non-silent) and their bootstrap CIs from per-episode rows alone (a CI
    is None where the rows give none: :func:`doabench.metrics.bootstrap.bootstrap_ci_from_sums`)."""
    out: dict[str, float | tuple[float, float] | None] = {}
    for stat, count in (("rmsae_all", "n_frames"), ("rmsae_nonsilent", "n_nonsilent")):
        sq, n = row_sums(rows, stat, count, squared=True)
        out[stat] = float(rms_from_sums(sq.sum(), n.sum()))
        out[f"{stat}_ci95"] = bootstrap_ci_from_sums(sq, n)
    out["n_episodes"] = len(rows)
    return out


def group_by(rows: Iterable[dict], keys: Sequence[str]) -> dict[tuple, list[dict]]:
    """Group per-episode rows by metadata keys (e.g. ``("t60", "snr")`` for grid cells)."""
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault(tuple(row.get(k) for k in keys), []).append(row)
    return groups
