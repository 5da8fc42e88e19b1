"""SRP-DNN's LOCATA protocol (Yang & Zheng, ICASSP 2022), on a recording's scored stamps.

Over the stamps where the source is voice-active, a stamp is *correct* when the track's azimuth is
within 30 degrees of the truth (a stamp without an estimate is not); accuracy is the share of
correct stamps, and the azimuth and inclination MAE and RMSE are taken over the correct stamps
only. Per recording; a task's values are the means over its recordings. Defined for one source.
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from doabench.geometry import wrap_angle

THRESHOLD_DEG = 30.0
FIELDS = ("accuracy", "az_mae_deg", "az_rmse_deg", "inc_mae_deg", "inc_rmse_deg")


def srp_dnn_scores(truth_az: np.ndarray, truth_inc: np.ndarray, vad: np.ndarray, est_az: np.ndarray,
                   est_inc: np.ndarray) -> dict[str, float]:
    """One recording: truth ``(T,)`` of its source, ``vad`` ``(T,)``, one track's estimates ``(T,)``
    (radians, NaN: none). Every field NaN when the source is never active."""
    active = np.asarray(vad, bool)
    with np.errstate(invalid="ignore"):
        az = np.degrees(np.abs(wrap_angle(np.asarray(est_az, float) - np.asarray(truth_az, float))))
        inc = np.degrees(np.abs(np.asarray(est_inc, float) - np.asarray(truth_inc, float)))
        correct = active & (az < THRESHOLD_DEG)
    if not active.any():
        return {name: math.nan for name in FIELDS}
    out = {"accuracy": float(correct.sum() / active.sum())}
    for name, err in (("az", az[correct]), ("inc", inc[correct])):
        err = err[~np.isnan(err)]
        out[f"{name}_mae_deg"] = float(err.mean()) if err.size else math.nan
        out[f"{name}_rmse_deg"] = float(np.sqrt(np.mean(err ** 2))) if err.size else math.nan
    return out


def recording_mean(recordings: Sequence[Mapping[str, Any]]) -> dict[str, float]:
    """The mean over recordings of each field (NaN and None left out)."""
    out = {}
    for name in FIELDS:
        values = np.asarray([r.get(name) for r in recordings], np.float64)
        values = values[~np.isnan(values)]
        out[name] = float(values.mean()) if values.size else math.nan
    return out
