"""Localisation and tracking metrics.

Definitions (all angles reported in degrees):

* frame error ``e_t``: great-circle angle between estimate and truth, ``atan2(|u x v|, u . v)``;
* ``rmsae_all`` = sqrt(mean_t e_t^2) over all frames; ``rmsae_nonsilent`` over voice-active frames
  only (the paper's two numbers: Fig. 6 excludes silent frames, Fig. 8 and Table II include them);
* ``mae``, ``median``, ``p90``: mean, median and 90th percentile of ``e_t`` (non-silent frames);
* ``within_5`` ... ``within_30``: share of non-silent frames with ``e_t`` at most 5/10/20/30 degrees;
* ``azimuth_mae``: mean wrapped azimuth error ``|wrap(az_est - az_true)|`` over voice-active frames,
  the LOCATA challenge's azimuth metric.

Which frames are scored, and how (:func:`score_frames`, the one place every score goes through:
``doabench run``, ``doabench track --truth``, the trainer's validation and the scripts): frames
whose truth is invalid (LOCATA ``valid_flag = 0``) are left out; for a planar array estimate and
truth are both mirror-folded onto the upper half-space (the array cannot tell a direction from its
mirror image); every remaining frame counts in ``rmsae_all`` and the voice-active ones in the
non-silent metrics.

Frames where the tracker said "no source" (three NaNs, ``doabench.NO_SOURCE``) have no estimate.
They stay in every pool and count the fixed error ``NO_SOURCE_ERROR_DEG`` (90 degrees, the mean
error of a direction drawn at random on the sphere), great-circle and azimuth alike, so saying
"no source" never scores better than a guess and every tracker's RMSAE pools the same frames;
the runner reports how many frames had no estimate (``no_estimate`` in the rows and the summary).
The lag leaves them out (they follow no path). A tracker that never says "no source" scores
exactly as before.

Aggregation over episodes comes in two labelled flavours: ``pooled`` (all frames of all episodes
in one pool, the paper's way) and ``episode_mean`` (the mean of per-episode values).

Tracking lag (beyond the paper): the delay ``tau`` of the truth, 0 to 2 s in steps of 0.05 s,
that minimises the RMSAE between the estimates and the truth delayed by ``tau``
(``truth(t - tau)``, interpolated between frames along the great circle's chord and normalised),
over the voice-active frames at least 2 s into the episode (the same frames for every ``tau``).
A tracker that follows the talker's path late by half a second has a lag of 0.5 s. A static or
nearly static source (median angular speed of the truth over those frames below 1 deg/s) has no
defined lag: every delay fits alike, and the lag is reported as None with the reason. Each
episode keeps its curve of summed squared errors per delay (``lag_sse``, ``lag_frames``), so the
pooled lag is the delay minimising the pooled curve over the episodes whose truth moves.

A lag is a property of estimates that follow the talker; a tracker that points one way (an
untrained network, a stuck tracker) fits some delay best by chance, often the end of the range.
So the lag is defined only when both hold for the pooled curve:

* the best delay is below the end of the search range (2 s), and
* the RMSAE at the best delay is below ``FOLLOW_RATIO`` (0.9) times that of the best constant
  direction over the same frames (per episode, ``lag_const_sse``: the smallest summed squared
  error one fixed direction, the spherical mean of the truth, reaches at any candidate delay).

A tracker with one fixed direction per episode can never pass the second test: its curve is
nowhere below ``lag_const_sse``. Otherwise the lag is None with the reason. Curves written before
``lag_const_sse`` was recorded are checked by the first test only.

RMSAE by angular speed: the voice-active frames split by the angular speed of the truth seen from
the array (central differences of the frame truth) into the bands of ``SPEED_BANDS``; each
episode keeps the summed squared errors and frame counts per band, pooled exactly.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterable, Sequence

import numpy as np

from doabench.geometry import (NO_SOURCE_ERROR_DEG, angular_speed_deg, fold_to_upper, great_circle_error,
                               is_no_source, normalize, unit_to_angles, wrap_angle)

THRESHOLDS_DEG = (5, 10, 20, 30)
LAG_MAX_S = 2.0
LAG_STEP_S = 0.05
STATIC_SPEED_DEG_S = 1.0
#: a lag is defined only where the RMSAE at the best delay is below this share of the best
#: constant direction's (module docstring): a clear margin, not a chance fit
FOLLOW_RATIO = 0.9
#: gradient steps of the spherical mean (it converges in a few for a path within a hemisphere)
KARCHER_STEPS = 20
#: angular-speed bands in deg/s, ``(label, low, high)``: low <= speed < high
SPEED_BANDS = (("<5", 0.0, 5.0), ("5-15", 5.0, 15.0), ("15-30", 15.0, 30.0), (">30", 30.0, float("inf")))


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
    the upper half-space (module docstring). The one scoring rule of doabench."""
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


def score_episode(estimates: np.ndarray, truth: np.ndarray, vad: np.ndarray, valid: np.ndarray | None = None,
                  planar: bool = False, times: np.ndarray | None = None) -> dict[str, Any]:
    """Every per-episode metric under the rules of :func:`score_frames`: ``frames_scored``,
    ``frames_invalid``, :func:`error_summary`'s metrics, then the lag and angular-speed bands
    (:func:`motion_metrics`, which need the evenly spaced frame ``times`` ``(T,)``; the whole
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
                 n_boot: int = 1000, level: float = 0.95, seed: int = 0) -> tuple[float, float] | None:
    """Bootstrap confidence interval over episodes (resampled with replacement) of a pooled RMSAE,
    or None where the episodes give none (:func:`defined_interval`).

    ``per_frame`` holds ``(errors_deg, vad)`` per episode; ``statistic`` is ``rmsae_all`` or
    ``rmsae_nonsilent``. Vectorised: per-episode sums of squares and counts are resampled.
    """
    if not per_frame:
        return None
    if statistic == "rmsae_all":
        sq = np.array([np.sum(np.square(e)) for e, _ in per_frame])
        n = np.array([e.size for e, _ in per_frame], float)
    elif statistic == "rmsae_nonsilent":
        sq = np.array([np.sum(np.square(e[np.asarray(v, bool)])) for e, v in per_frame])
        n = np.array([np.sum(v) for _, v in per_frame], float)
    else:
        raise ValueError(f"bootstrap_ci supports rmsae_all and rmsae_nonsilent, not {statistic!r}")
    return bootstrap_ci_from_sums(sq, n, n_boot, level, seed)


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

    The one bootstrap of doabench: a results file's intervals draw from one stratum (every
    episode), ``doabench compare`` draws within each grid cell (the stratified bootstrap of
    ``rliable``, Agarwal et al., NeurIPS 2021) where every cell holds at least
    :data:`MIN_STRATUM` episodes, else across the task (:func:`bootstrap_strata`). A statistic of resample ``r`` is then computed
    from ``counts[r] @ per_episode_sums``."""
    rng = np.random.default_rng(seed)
    counts = np.zeros((n_resamples, n_episodes))
    base = np.arange(n_resamples)[:, None] * n_episodes
    for members in strata:
        members = np.asarray(members, np.int64)
        draws = members[rng.integers(0, len(members), size=(n_resamples, len(members)))]
        counts += np.bincount((base + draws).ravel(), minlength=n_resamples * n_episodes).reshape(
            n_resamples, n_episodes)
    return counts


def _resampled_rms(counts: np.ndarray, sq: np.ndarray, n: np.ndarray) -> np.ndarray:
    """``(n_resamples,)`` pooled RMS of each resample (rows of ``counts``) from per-episode sums."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt((counts @ sq) / (counts @ n))


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
    results file is written, the views (:func:`doabench.results.intervals.shown_interval`) when
    they print one, so a file written before the rule reads the same as one written since."""
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
    values = _resampled_rms(bootstrap_counts([np.arange(sq.size)], sq.size, n_boot, seed), sq, n)
    if np.all(np.isnan(values)):
        return None
    lo, hi = np.nanpercentile(values, [(1 - level) / 2 * 100, (1 + level) / 2 * 100])
    with np.errstate(invalid="ignore", divide="ignore"):
        episode_rms = np.sqrt(sq / n)
    return defined_interval(episode_rms, n, (float(lo), float(hi)))


def pooled_from_rows(rows: Sequence[dict]) -> dict[str, float | tuple[float, float] | None]:
    """Pooled RMSAEs (all / non-silent) and their bootstrap CIs from per-episode rows alone (a CI
    is None where the rows give none: :func:`bootstrap_ci_from_sums`).

    Exact: a pooled RMS is sqrt(sum_i n_i rms_i^2 / sum_i n_i) over episodes i.
    """
    out: dict[str, float | tuple[float, float] | None] = {}
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


def lag_grid(max_lag_s: float = LAG_MAX_S, step_s: float = LAG_STEP_S) -> np.ndarray:
    """The candidate delays in seconds, ``(D,)``: 0, step, ..., max."""
    return np.round(np.arange(int(round(max_lag_s / step_s)) + 1) * step_s, 10)


def delayed_truth(truth: np.ndarray, delays_frames: np.ndarray) -> np.ndarray:
    """``truth(t - d)`` for every delay ``d`` (in frames, fractional) ``(D,)`` and frame ``t`` of
    ``truth`` ``(T, 3)``: ``(D, T, 3)`` unit vectors, linear between neighbouring frames then
    normalised; NaN where ``t - d`` lies before the first frame."""
    u = np.asarray(truth, np.float64)
    T = len(u)
    pos = np.arange(T)[None, :] - np.asarray(delays_frames, np.float64)[:, None]  # (D, T)
    i0 = np.floor(pos).astype(np.int64)
    w = (pos - i0)[..., None]
    lo = u[np.clip(i0, 0, T - 1)]
    hi = u[np.clip(i0 + 1, 0, T - 1)]
    out = normalize((1.0 - w) * lo + w * hi)
    out[pos < 0] = np.nan
    return out


def best_constant_sse(directions: np.ndarray) -> np.ndarray:
    """The smallest summed squared error (deg^2) one fixed direction reaches against each row of
    unit ``directions`` ``(D, n, 3)``: ``(D,)``. The direction is the row's spherical (Karcher)
    mean, found by gradient steps from the normalised mean; the best step is kept."""
    u = np.asarray(directions, np.float64)
    centre = normalize(u.sum(axis=-2))
    centre = np.where(np.linalg.norm(centre, axis=-1, keepdims=True) > 0.5, centre, u[..., 0, :])
    best = np.full(u.shape[:-2], np.inf)
    for _ in range(KARCHER_STEPS + 1):
        angle = great_circle_error(u, centre[..., None, :])  # (D, n) radians
        best = np.minimum(best, np.square(np.degrees(angle)).sum(-1))
        # the mean of the log map (each point as a tangent vector at the centre, its length the angle)
        perp = u - np.sum(u * centre[..., None, :], -1, keepdims=True) * centre[..., None, :]
        length = np.linalg.norm(perp, axis=-1, keepdims=True)
        step = np.mean(np.where(length > 0, perp * angle[..., None] / np.where(length > 0, length, 1.0), 0.0), -2)
        theta = np.linalg.norm(step, axis=-1, keepdims=True)
        centre = normalize(np.cos(theta) * centre + np.sinc(theta / np.pi) * step)  # the exponential map
    return best


def lag_curve(estimates: np.ndarray, truth: np.ndarray, vad: np.ndarray, frame_period_s: float,
              max_lag_s: float = LAG_MAX_S, step_s: float = LAG_STEP_S) -> dict:
    """An episode's lag evidence (module docstring): ``{"lag_sse": (D,) summed squared errors in
    deg^2 per delay of :func:`lag_grid`, "lag_const_sse": the smallest of the best constant
    direction's (:func:`best_constant_sse`) over the delays, "lag_frames": frames used (voice-active,
    with an estimate),
    "lag_speed": median angular speed of the truth over them (deg/s)}``. ``estimates``,
    ``truth`` ``(T, 3)``, ``vad`` ``(T,)``."""
    est = np.asarray(estimates, np.float64)
    u = np.asarray(truth, np.float64)
    lags = lag_grid(max_lag_s, step_s)
    first = int(np.ceil(max_lag_s / frame_period_s - 1e-9))
    use = np.asarray(vad, bool) & ~is_no_source(est)  # a frame without an estimate follows no path
    use[:first] = False
    if not use.any():
        return {"lag_sse": [0.0] * len(lags), "lag_const_sse": 0.0, "lag_frames": 0, "lag_speed": None}
    delayed = delayed_truth(u, lags / frame_period_s)[:, use]  # (D, n, 3)
    errors = frame_errors_deg(np.broadcast_to(est[use], delayed.shape), delayed)  # (D, n)
    speed = angular_speed_deg(u, frame_period_s)[use]
    return {"lag_sse": np.square(errors).sum(1).tolist(), "lag_const_sse": float(best_constant_sse(delayed).min()),
            "lag_frames": int(use.sum()), "lag_speed": float(np.median(speed))}


def follows(total_sse: np.ndarray, const_sse: np.ndarray | float) -> np.ndarray:
    """Whether pooled lag curves ``(..., D)`` are of estimates that follow the talker (module
    docstring): the best delay is below the end of the range and its error below ``FOLLOW_RATIO``
    times the best constant direction's ``const_sse`` ``(...)`` (NaN: not recorded, not tested)."""
    total, const = np.asarray(total_sse, np.float64), np.asarray(const_sse, np.float64)
    best = np.argmin(total, axis=-1)
    inside = best < total.shape[-1] - 1
    clearly = np.isnan(const) | (np.min(total, axis=-1) < FOLLOW_RATIO ** 2 * const)
    return inside & clearly


def moves(curve: dict) -> bool:
    """Whether an episode's lag evidence (:func:`lag_curve`) has frames and a truth that moves."""
    speed = curve.get("lag_speed")
    return curve.get("lag_frames", 0) > 0 and speed is not None and speed >= STATIC_SPEED_DEG_S


def lag_from_curves(curves: Sequence[dict], max_lag_s: float = LAG_MAX_S,
                    step_s: float = LAG_STEP_S) -> tuple[float | None, str]:
    """The lag in seconds minimising the summed curves of the episodes whose truth moves, and a
    note: ``(lag, "")``, or ``(None, reason)`` when no episode's truth moves or the estimates do
    not follow it (:func:`follows`)."""
    moving = [c for c in curves if moves(c)]
    if not moving:
        if any(c.get("lag_frames", 0) > 0 for c in curves):
            return None, f"static source (truth moves below {STATIC_SPEED_DEG_S:g} deg/s): no defined lag"
        return None, f"no voice-active frame after the first {max_lag_s:g} s: no defined lag"
    total = np.sum([np.asarray(c["lag_sse"], np.float64) for c in moving], axis=0)
    best = int(np.argmin(total))
    if best == len(total) - 1:
        return None, f"best fit at the end of the {max_lag_s:g} s search range (not following the talker): no defined lag"
    if not follows(total, pooled_const_sse(moving)):
        return None, (f"not following the talker (RMSAE at the best delay not below {FOLLOW_RATIO:g} x the best "
                      "constant direction's): no defined lag")
    return float(lag_grid(max_lag_s, step_s)[best]), ""


def pooled_const_sse(curves: Sequence[dict]) -> float:
    """The summed ``lag_const_sse`` of the curves; NaN when one lacks it (written before it was recorded)."""
    values = [c.get("lag_const_sse") for c in curves]
    return float(np.sum([float("nan") if v is None else float(v) for v in values]))


def speed_band_sums(errors: np.ndarray, truth: np.ndarray, vad: np.ndarray, frame_period_s: float) -> dict:
    """Summed squared errors and frame counts of the voice-active frames per angular-speed band
    of the truth: ``{label: [sse, n]}`` (``errors`` ``(T,)`` deg, ``truth`` ``(T, 3)``)."""
    e = np.asarray(errors, np.float64)
    speed = angular_speed_deg(np.asarray(truth, np.float64), frame_period_s)
    active = np.asarray(vad, bool)
    out = {}
    for label, lo, hi in SPEED_BANDS:
        m = active & (speed >= lo) & (speed < hi)
        out[label] = [float(np.square(e[m]).sum()), int(m.sum())]
    return out


def pooled_speed_bands(rows: Sequence[dict]) -> dict[str, dict]:
    """Pooled RMSAE per angular-speed band from per-episode ``speed_bands`` sums:
    ``{label: {"rmsae": deg or NaN, "n_frames": n}}``."""
    out = {}
    for label, _, _ in SPEED_BANDS:
        sse = sum(r["speed_bands"][label][0] for r in rows if "speed_bands" in r)
        n = sum(r["speed_bands"][label][1] for r in rows if "speed_bands" in r)
        out[label] = {"rmsae": float(np.sqrt(sse / n)) if n else float("nan"), "n_frames": int(n)}
    return out


def motion_metrics(estimates: np.ndarray, truth: np.ndarray, vad: np.ndarray, frame_period_s: float) -> dict:
    """An episode's lag (s, or None with ``lag_note``), its lag curve and its angular-speed band
    sums, from ``estimates``, ``truth`` ``(T, 3)`` and ``vad`` ``(T,)``."""
    curve = lag_curve(estimates, truth, vad, frame_period_s)
    lag, note = lag_from_curves([curve])
    errors = frame_errors_deg(estimates, truth)
    return {"lag_s": lag, **({"lag_note": note} if note else {}), **curve,
            "speed_bands": speed_band_sums(errors, truth, vad, frame_period_s)}
