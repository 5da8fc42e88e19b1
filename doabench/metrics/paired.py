"""The paired bootstrap: the difference of a pooled statistic between two runs on the same episodes.

Two runs of the same episodes saw the same rooms, trajectories and speech, so what makes an episode
hard for both cancels in the difference. Every resample draws the same episodes for both runs
(:func:`doabench.metrics.bootstrap.bootstrap_counts`, within the strata
:func:`doabench.metrics.bootstrap.bootstrap_strata` allows), the statistic (a :class:`Metric`) is
recomputed for each run from the drawn episodes, and the percentile interval of the difference is
the interval (:func:`doabench.metrics.bootstrap.percentile_interval`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from doabench.metrics.bootstrap import bootstrap_counts, bootstrap_strata, percentile_interval
from doabench.metrics.pooled import FrameRecords, Metric, Rows


def weighted_quantile(values: np.ndarray, owner: np.ndarray, counts: np.ndarray, q: float) -> np.ndarray:
    """The ``q`` quantile (inverted CDF) of ``values`` with each value repeated as often as its
    episode (``owner``: its position) was drawn: ``counts`` ``(B, episodes)`` -> ``(B,)``."""
    if values.size == 0:
        return np.full(len(counts), np.nan)
    order = np.argsort(values, kind="stable")
    v, o = values[order], owner[order]
    out = np.empty(len(counts))
    for start in range(0, len(counts), 64):  # chunks: (64, frames) weights at a time
        w = counts[start:start + 64][:, o]
        cw = np.cumsum(w, axis=1)
        total = cw[:, -1:]
        at = np.argmax(cw >= q * total - 1e-9, axis=1)
        out[start:start + 64] = np.where(total[:, 0] > 0, v[at], np.nan)
    return out


def resampled_values(metric: Metric, sums: np.ndarray, frames: FrameRecords, counts: np.ndarray) -> np.ndarray:
    """The statistic for each row of ``counts`` ``(B, episodes)`` from the episodes' ``sums``
    (``metric.stats``) or, for a frame quantile, the samples of their ``frames``."""
    if metric.quantile is not None:
        assert metric.samples is not None, "a frame quantile needs the frame values to take it of"
        values, owner = metric.samples(frames or [])
        return weighted_quantile(values, owner, counts, metric.quantile)
    return metric.value(counts @ sums)


def point_value(metric: Metric, sums: np.ndarray, frames: FrameRecords) -> float:
    """The statistic of all the episodes once each; a frame quantile exactly as the leaderboards
    compute it (linear interpolation, :func:`numpy.percentile`)."""
    if metric.quantile is not None:
        assert metric.samples is not None and frames is not None, "a frame quantile needs frame records"
        values = metric.samples(frames)[0]
        return float(np.percentile(values, 100 * metric.quantile)) if values.size else float("nan")
    return float(resampled_values(metric, sums, frames, np.ones((1, len(sums))))[0])


@dataclass(frozen=True)
class PairedDifference:
    """A statistic of runs ``a`` and ``b`` on the same episodes and the interval of ``a - b``."""

    a: float
    b: float
    #: percentile interval of the resampled differences (NaN where no resample gave one)
    low: float
    high: float
    #: episodes that contribute to the statistic in both runs (frames of it in each)
    n_contributing: int
    #: whether the resamples drew within the strata (else across every episode)
    stratified: bool


def paired_difference(metric: Metric, rows_a: Rows, rows_b: Rows, frames_a: FrameRecords, frames_b: FrameRecords,
                      strata: Sequence[np.ndarray], n_resamples: int, seed: int,
                      level: float = 0.95) -> PairedDifference:
    """``metric`` of the episodes ``rows_a`` and ``rows_b`` (the same episodes, in the same order,
    with their frame records or None) and the ``level`` interval of the paired difference ``a - b``
    over ``n_resamples`` resamples drawn within ``strata`` (positions in the rows) where each holds
    enough episodes (:func:`doabench.metrics.bootstrap.bootstrap_strata`)."""
    n = len(rows_a)
    sums_a, sums_b = metric.stats(rows_a, frames_a), metric.stats(rows_b, frames_b)
    strata, stratified = bootstrap_strata(strata, n)
    counts = bootstrap_counts(strata, n, n_resamples, seed)
    diffs = resampled_values(metric, sums_a, frames_a, counts) - resampled_values(metric, sums_b, frames_b, counts)
    low, high = percentile_interval(diffs, level) or (float("nan"), float("nan"))
    return PairedDifference(point_value(metric, sums_a, frames_a), point_value(metric, sums_b, frames_b), low, high,
                            int(np.sum((sums_a[:, -1] > 0) & (sums_b[:, -1] > 0))), stratified)
