"""The one bootstrap of doabench: episodes resampled with replacement (within strata where each
holds enough), and the 95 % intervals it gives.

A results file's intervals draw from one stratum, every episode (:func:`bootstrap_ci_from_sums`);
``doabench compare`` draws the same episodes for both runs, within each grid cell where every cell
holds at least :data:`MIN_STRATUM` episodes (:func:`doabench.metrics.paired.paired_difference`).
Both take the percentile interval of the resampled statistic (:func:`percentile_interval`).
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from doabench.metrics.scoring import rms_from_sums, squared_error_sums

#: the fewest episodes every stratum must hold for a bootstrap to draw within strata (:func:`bootstrap_strata`)
MIN_STRATUM = 5


def bootstrap_strata(strata: Sequence[np.ndarray], n_episodes: int,
                     min_size: int = MIN_STRATUM) -> tuple[list[np.ndarray], bool]:
    """The strata a bootstrap draws within, and whether it is stratified: ``strata`` when every
    one holds at least ``min_size`` episodes, else one stratum of all ``n_episodes`` (the
    episodes are drawn across the whole task).

    A stratum of one episode gives it in every resample, and one of two gives three values: a
    bootstrap stratified over such strata has an interval of (nearly) no width, which claims a
    certainty the data do not have. Drawn across the task, the interval holds the spread between
    the episodes of different strata too, which is wider than the stratified one: the honest side."""
    strata = [np.asarray(s, np.int64) for s in strata]
    if len(strata) > 1 and all(len(s) >= min_size for s in strata):
        return strata, True
    return [np.arange(n_episodes)], False


def bootstrap_counts(strata: Sequence[np.ndarray], n_episodes: int, n_resamples: int = 1000,
                     seed: int = 0) -> np.ndarray:
    """``(n_resamples, n_episodes)``: how often each episode is drawn in each resample, drawing
    within each stratum (positions in ``strata``) as many episodes as it holds, with replacement.

    The one resampler of doabench: a results file's intervals draw from one stratum (every
    episode), ``doabench compare`` draws within each grid cell (the stratified bootstrap of
    ``rliable``, Agarwal et al., NeurIPS 2021) where every cell holds at least
    :data:`MIN_STRATUM` episodes, else across the task (:func:`bootstrap_strata`). A statistic of
    resample ``r`` is then computed from ``counts[r] @ per_episode_sums``."""
    rng = np.random.default_rng(seed)
    counts = np.zeros((n_resamples, n_episodes))
    base = np.arange(n_resamples)[:, None] * n_episodes
    for members in strata:
        members = np.asarray(members, np.int64)
        draws = members[rng.integers(0, len(members), size=(n_resamples, len(members)))]
        counts += np.bincount((base + draws).ravel(), minlength=n_resamples * n_episodes).reshape(
            n_resamples, n_episodes)
    return counts


def percentile_interval(values: np.ndarray, level: float = 0.95) -> tuple[float, float] | None:
    """The percentile interval at ``level`` of the resampled ``values`` that are numbers (a
    resample without a defined statistic, NaN, has no say); None when none is."""
    values = np.asarray(values, np.float64)
    values = values[np.isfinite(values)]
    if not values.size:
        return None
    low, high = np.percentile(values, [(1 - level) / 2 * 100, (1 + level) / 2 * 100])
    return float(low), float(high)


#: the fewest episodes with scored frames that give a results file (or a grid cell) an interval of
#: its own: a resample of one episode is that episode every time, and two give three values, so
#: fewer would claim a certainty (an interval of no or next to no width) the data do not have
MIN_INTERVAL_EPISODES = 3
#: relative width below which an interval counts as having none
_NO_WIDTH = 1e-9


def defined_interval(episode_rms: Sequence[float] | np.ndarray, episode_frames: Sequence[float] | np.ndarray,
                     interval: Sequence[float] | None,
                     min_episodes: int = MIN_INTERVAL_EPISODES) -> tuple[float, float] | None:
    """``interval`` as ``(low, high)`` where the episodes back it, else None: None when it is
    missing or not two finite numbers, when fewer than ``min_episodes`` episodes have scored frames
    (``episode_frames`` > 0; an episode without frames adds nothing to a pooled RMS), or when it
    has no width although those episodes' RMS values (``episode_rms``) differ (every resample gave
    the same value, so the interval says nothing about the spread). Episodes that all score the
    same keep their interval of no width: there is no spread to show.

    The one rule for a single run's interval: :func:`bootstrap_ci_from_sums` applies it when a
    results file is written, the upgrade of a file written before the rule
    (:func:`doabench.results.intervals.drop_undefined_intervals`) when it is read, so both read alike."""
    if interval is None:
        return None
    try:
        low, high = (float(v) for v in interval)
    except (TypeError, ValueError):
        return None
    if not (math.isfinite(low) and math.isfinite(high)):
        return None
    rms = np.asarray(episode_rms, np.float64).reshape(-1)
    frames = np.asarray(episode_frames, np.float64).reshape(-1)
    scored = rms[(frames > 0) & np.isfinite(rms)] if rms.shape == frames.shape else rms[:0]
    if scored.size < min_episodes:
        return None
    no_width = high - low <= _NO_WIDTH * max(1.0, abs(high))
    if no_width and not np.allclose(scored, scored[0], rtol=_NO_WIDTH, atol=0.0):
        return None
    return low, high


def bootstrap_ci_from_sums(sum_sq: np.ndarray, counts: np.ndarray, n_boot: int = 1000, level: float = 0.95,
                           seed: int = 0) -> tuple[float, float] | None:
    """Bootstrap CI of a pooled RMS from per-episode sums of squared errors and frame counts
    (episodes resampled with replacement, :func:`bootstrap_counts` with one stratum), or None where
    the episodes give no interval (:func:`defined_interval`: fewer than
    :data:`MIN_INTERVAL_EPISODES` with frames, or no spread between resamples of differing episodes)."""
    sq, n = np.asarray(sum_sq, float), np.asarray(counts, float)
    if sq.size == 0:
        return None
    draws = bootstrap_counts([np.arange(sq.size)], sq.size, n_boot, seed)
    interval = percentile_interval(rms_from_sums(draws @ sq, draws @ n), level)
    return defined_interval(rms_from_sums(sq, n), n, interval)


def bootstrap_ci(per_frame: Sequence[tuple[np.ndarray, np.ndarray]], statistic: str = "rmsae_nonsilent",
                 n_boot: int = 1000, level: float = 0.95, seed: int = 0) -> tuple[float, float] | None:
    """Bootstrap confidence interval over episodes (resampled with replacement) of a pooled RMSAE,
    or None where the episodes give none (:func:`defined_interval`).

    ``per_frame`` holds ``(errors_deg, vad)`` per episode; ``statistic`` is ``rmsae_all`` or
    ``rmsae_nonsilent``. Vectorised: per-episode sums of squares and counts are resampled.
    """
    if not per_frame:
        return None
    if statistic == "rmsae_all":
        sq, n = squared_error_sums(e for e, _ in per_frame)
    elif statistic == "rmsae_nonsilent":
        sq, n = squared_error_sums(np.asarray(e)[np.asarray(v, bool)] for e, v in per_frame)
    else:
        raise ValueError(f"bootstrap_ci supports rmsae_all and rmsae_nonsilent, not {statistic!r}")
    return bootstrap_ci_from_sums(sq, n, n_boot, level, seed)
