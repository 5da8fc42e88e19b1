"""Tracking lag and RMSAE by angular speed: the metrics of a moving talker.

The definitions (the lag search, when a lag is defined, the speed bands) are those of
:mod:`doabench.metrics`.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from doabench.geometry import angular_speed_deg, great_circle_error, is_no_source, normalize
from doabench.metrics.scoring import frame_errors_deg, rms_from_sums

LAG_MAX_S = 2.0
LAG_STEP_S = 0.05
STATIC_SPEED_DEG_S = 1.0
#: a lag is defined only where the RMSAE at the best delay is below this share of the best
#: constant direction's (:mod:`doabench.metrics`): a clear margin, not a chance fit
FOLLOW_RATIO = 0.9
#: gradient steps of the spherical mean (it converges in a few for a path within a hemisphere)
KARCHER_STEPS = 20
#: angular-speed bands in deg/s, ``(label, low, high)``: low <= speed < high
SPEED_BANDS = (("<5", 0.0, 5.0), ("5-15", 5.0, 15.0), ("15-30", 15.0, 30.0), (">30", 30.0, float("inf")))


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
    """An episode's lag evidence (:mod:`doabench.metrics`): ``{"lag_sse": (D,) summed squared errors in
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
    """Whether pooled lag curves ``(..., D)`` are of estimates that follow the talker
    (:mod:`doabench.metrics`): the best delay is below the end of the range and its error below
    ``FOLLOW_RATIO`` times the best constant direction's ``const_sse`` ``(...)`` (NaN: not
    recorded, not tested)."""
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
        out[label] = {"rmsae": float(rms_from_sums(sse, n)), "n_frames": int(n)}
    return out


def motion_metrics(estimates: np.ndarray, truth: np.ndarray, vad: np.ndarray, frame_period_s: float) -> dict:
    """An episode's lag (s, or None with ``lag_note``), its lag curve and its angular-speed band
    sums, from ``estimates``, ``truth`` ``(T, 3)`` and ``vad`` ``(T,)``."""
    curve = lag_curve(estimates, truth, vad, frame_period_s)
    lag, note = lag_from_curves([curve])
    errors = frame_errors_deg(estimates, truth)
    return {"lag_s": lag, **({"lag_note": note} if note else {}), **curve,
            "speed_bands": speed_band_sums(errors, truth, vad, frame_period_s)}
