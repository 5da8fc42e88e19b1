"""The LOCATA challenge's tracking measures on one recording's required time stamps.

Inputs of one recording and array (angles in radians, every array on the same stamps):

* ``times`` ``(T,)``: the scored stamps (``required_time.txt`` rows with ``valid_flag`` 1), seconds;
* truth ``azimuth``/``inclination`` ``(S, T)`` of every source and its voice activity ``vad``
  ``(S, T)`` (0/1);
* estimates ``azimuth``/``inclination`` ``(K, T)`` of every track; NaN where a track gives no
  estimate (an azimuth that is a number makes the track *active* at that stamp).

Per stamp, a 30-degree gate and the optimal one-to-one assignment of the active tracks to the
sources (:func:`score_stamps`); per voice-active period of each source the azimuth and inclination
errors, the probability of detection, track latency, swap and fragmentation rates; per recording
the false-alarm rates, MOTA and OSPA (:func:`recording_measures`); over a task, the pooled means of
the challenge's tables (:func:`task_averages`). docs/locata.md ("The challenge's measures") gives
every definition and the two modes:

* ``official`` reproduces the challenge's released evaluation, departures from the paper included;
* ``corrected`` follows the paper: voice-active periods are the runs of activity as they are,
  track latency runs from a period's start to its first detection, the ungated inclination error
  is an inclination distance, and only voice-active sources can be missed.

A measure with nothing to average (a source without a voice-active period) is NaN with a warning.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

from doabench.errors import ConfigError, InputError
from doabench.geometry import wrap_angle

MODES = ("official", "corrected")
GATE_DEG = 30.0
OSPA_CUTOFF_DEG = 30.0
OSPA_ORDERS = (1.0, 1.5, 2.0, 5.0)


def ospa_key(order: float) -> str:
    """The name of an OSPA order in results: ``"1"``, ``"1.5"``, ``"2"``, ``"5"``."""
    return f"{order:g}"


def check_mode(mode: str) -> str:
    """``mode`` if it is one of :data:`MODES`, else ConfigError."""
    if mode not in MODES:
        raise ConfigError(f"LOCATA measures {mode!r} are not one of {', '.join(MODES)}")
    return mode


# -- per stamp -------------------------------------------------------------------------------------
@dataclass
class StampScores:
    """What :func:`score_stamps` finds at every stamp (``S`` sources, ``K`` tracks, ``T`` stamps).

    * ``assigned`` ``(S, T)`` int: the track assigned to each source, -1 for none;
    * ``az_error``/``inc_error`` ``(S, T)`` radians: a voice-active source's distance to its
      assigned track, NaN elsewhere (and where the track has no inclination);
    * ``az_distance``/``inc_distance`` ``(S, K, T)`` radians: the ungated distance of every source
      to every active track, at stamps with active sources and active tracks; NaN elsewhere;
    * ``missed`` ``(S, T)`` bool, ``false`` ``(T,)`` int (false tracks), ``swaps`` ``(S, T)`` bool;
    * ``ospa`` ``(len(OSPA_ORDERS), T)`` degrees, NaN where neither sources nor tracks are active.
    """

    assigned: np.ndarray
    az_error: np.ndarray
    inc_error: np.ndarray
    az_distance: np.ndarray
    inc_distance: np.ndarray
    missed: np.ndarray
    false: np.ndarray
    swaps: np.ndarray
    ospa: np.ndarray


def assign(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The optimal one-to-one assignment on ``cost`` ``(S, K)``, where ``inf`` forbids a pair:
    as many pairs as the finite entries allow, of least total cost. ``(rows, cols)``, finite pairs only."""
    finite = np.isfinite(cost)
    if not finite.any():
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    # A forbidden pair costs more than every finite pair together, so the solver takes one only
    # where no finite one is left; such pairs are dropped afterwards.
    big = 2.0 * (float(np.abs(cost[finite]).sum()) + 1.0)
    rows, cols = linear_sum_assignment(np.where(finite, cost, big))
    keep = finite[rows, cols]
    return rows[keep], cols[keep]


def _swaps(assigned: np.ndarray) -> np.ndarray:
    """``(S, T)`` bool: a source's assigned track differs from the last one it had (its first
    assignment is no swap; stamps without one are skipped)."""
    n_src, n_stamps = assigned.shape
    has = assigned >= 0
    last = np.maximum.accumulate(np.where(has, np.arange(n_stamps), -1), axis=1)  # last stamp <= t with a track
    before = np.concatenate([np.full((n_src, 1), -1), last[:, :-1]], axis=1)
    previous = np.where(before >= 0, np.take_along_axis(assigned, np.maximum(before, 0), axis=1), -1)
    return has & (previous >= 0) & (assigned != previous)


def _check_shapes(truth_az: np.ndarray, truth_inc: np.ndarray, vad: np.ndarray, est_az: np.ndarray,
                  est_inc: np.ndarray) -> None:
    if truth_az.ndim != 2 or truth_inc.shape != truth_az.shape or vad.shape != truth_az.shape:
        raise InputError(f"LOCATA truth must be (sources, stamps) arrays of one shape, got {truth_az.shape}, "
                         f"{truth_inc.shape}, {vad.shape}")
    if est_az.ndim != 2 or est_inc.shape != est_az.shape or est_az.shape[1] != truth_az.shape[1]:
        raise InputError(f"LOCATA estimates must be (tracks, stamps) arrays on the truth's {truth_az.shape[1]} "
                         f"stamps, got {est_az.shape} and {est_inc.shape}")


def score_stamps(truth_az: np.ndarray, truth_inc: np.ndarray, vad: np.ndarray, est_az: np.ndarray,
                 est_inc: np.ndarray, mode: str = "official") -> StampScores:
    """Gate, assign and count at every stamp (shapes in the module docstring; radians)."""
    check_mode(mode)
    truth_az, truth_inc = np.asarray(truth_az, np.float64), np.asarray(truth_inc, np.float64)
    est_az, est_inc = np.asarray(est_az, np.float64), np.asarray(est_inc, np.float64)
    vad = np.asarray(vad).astype(bool)
    _check_shapes(truth_az, truth_inc, vad, est_az, est_inc)
    n_src, n_stamps = truth_az.shape
    active = np.isfinite(est_az)  # (K, T)
    with np.errstate(invalid="ignore"):
        dist = np.abs(wrap_angle(truth_az[:, None, :] - est_az[None, :, :]))  # (S, K, T), NaN: inactive
        inc_dist = np.abs(truth_inc[:, None, :] - est_inc[None, :, :])
    n_on, n_tracks = vad.sum(0), active.sum(0)  # (T,) each
    both = (n_on > 0) & (n_tracks > 0)
    inc_dist = np.where(active[None], inc_dist, np.nan)
    az_distance = np.where(both[None, None, :], dist, np.nan)
    inc_distance = np.where(both[None, None, :], inc_dist, np.nan)

    false = np.where(n_on == 0, n_tracks, 0).astype(np.int64)
    missed = vad & (n_tracks == 0)[None, :]
    assigned = np.full((n_src, n_stamps), -1, np.int64)
    cutoff = OSPA_CUTOFF_DEG
    ospa = np.full((len(OSPA_ORDERS), n_stamps), np.nan)
    ospa[:, (n_on > 0) != (n_tracks > 0)] = cutoff  # only sources or only tracks: the cut-off
    gate = math.radians(GATE_DEG)
    for t in np.flatnonzero(both):
        d = dist[:, :, t]
        known = np.isfinite(d)
        rows, cols = assign(np.where(known & (d <= gate), d, np.inf))
        assigned[rows, t] = cols
        false[t] = n_tracks[t] - len(cols)
        # OSPA: every source against every track on the ungated distance, capped at the cut-off
        # (an inactive track costs the cut-off).
        capped = np.where(known, np.minimum(cutoff, np.degrees(np.where(known, d, 0.0))), cutoff)
        size, excess = max(n_tracks[t], n_on[t]), abs(int(n_tracks[t]) - int(n_on[t]))
        for i, p in enumerate(OSPA_ORDERS):
            cost = capped ** p
            r, c = linear_sum_assignment(cost)
            ospa[i, t] = ((cutoff ** p * excess + cost[r, c].sum()) / size) ** (1.0 / p)
    has = assigned >= 0
    # As released every source without a track is missed, voice-active or not; corrected: active ones.
    unassigned = both[None, :] & ~has
    missed |= unassigned if mode == "official" else unassigned & vad
    index = np.maximum(assigned, 0)[:, None, :]
    on_track = vad & has
    az_error = np.where(on_track, np.take_along_axis(dist, index, axis=1)[:, 0, :], np.nan)
    inc_error = np.where(on_track, np.take_along_axis(inc_dist, index, axis=1)[:, 0, :], np.nan)
    return StampScores(assigned, az_error, inc_error, az_distance, inc_distance, missed, false, _swaps(assigned), ospa)


# -- voice-active periods ----------------------------------------------------------------------
def voice_periods(vad: npt.ArrayLike, mode: str = "official") -> list[tuple[int, int]]:
    """``(first, last)`` stamp indices of the voice-active periods of ``vad`` ``(T,)``.

    ``corrected``: the maximal runs of activity. ``official``: as released, a start is a 0 -> 1
    step between consecutive stamps and an end a 1 -> 0 step (or the last stamp while a run is
    open), and starts and ends are paired in order; so a run already active at the first stamp
    has no start, every later start is paired with the previous run's end (``first > last``: a
    period without stamps) and there are as many periods as starts.
    """
    check_mode(mode)
    v = np.asarray(vad).astype(bool)
    if v.size == 0:
        return []
    if mode == "corrected":
        starts = np.flatnonzero(v & ~np.concatenate([[False], v[:-1]]))
    else:
        starts = np.flatnonzero(~v[:-1] & v[1:]) + 1
    ends = np.flatnonzero(v[:-1] & ~v[1:])
    if v[-1]:
        ends = np.append(ends, len(v) - 1)
    return [(int(a), int(b)) for a, b in zip(starts, ends)]


def _mean(values: np.ndarray | Sequence[float]) -> float:
    """The mean of the values that are not NaN; NaN when there are none."""
    x = np.asarray(values, np.float64).ravel()
    x = x[~np.isnan(x)]
    return float(x.mean()) if x.size else math.nan


def _rate(count: float, duration: float) -> float:
    """``count / duration``; NaN for a period of no duration (a single stamp)."""
    return math.nan if duration == 0 else float(count) / duration + 0.0  # + 0.0: no -0.0


# -- per recording -----------------------------------------------------------------------------
@dataclass
class SourceMeasures:
    """One source's measures: lists hold one value per voice-active period (degrees, seconds)."""

    periods_s: list[tuple[float, float]] = field(default_factory=list)
    az_error_deg: list[float] = field(default_factory=list)
    az_error_ungated_deg: list[float] = field(default_factory=list)
    inc_error_deg: list[float] = field(default_factory=list)
    inc_error_ungated_deg: list[float] = field(default_factory=list)
    pd: list[float] = field(default_factory=list)
    latency_s: float = math.nan
    swap_rate: float = math.nan
    frag_rate: float = math.nan
    swaps: int = 0

    def to_json(self) -> dict[str, Any]:
        return {"az_error_deg": self.az_error_deg, "az_error_ungated_deg": self.az_error_ungated_deg,
                "inc_error_deg": self.inc_error_deg, "inc_error_ungated_deg": self.inc_error_ungated_deg,
                "pd": self.pd, "latency_s": self.latency_s, "swap_rate": self.swap_rate,
                "frag_rate": self.frag_rate, "swaps": self.swaps,
                "periods_s": [list(p) for p in self.periods_s]}


@dataclass
class RecordingMeasures:
    """One recording's measures: ``sources`` by name, ``far``/``far_vap`` (false tracks per
    second), ``mota`` (one value per source), ``ospa_deg`` (mean over the stamps where OSPA is
    defined, per order) and the per-stamp scores they come from."""

    mode: str
    sources: dict[str, SourceMeasures]
    far: float
    far_vap: float
    mota: list[float]
    ospa_deg: dict[str, float]
    stamps: StampScores
    n_stamps: int

    def to_json(self) -> dict[str, Any]:
        """The measures as the results store them (``ospa_stamps``: per order, the stamps where
        OSPA is defined, which weight the recording in a task's OSPA)."""
        defined = {ospa_key(p): int(np.isfinite(self.stamps.ospa[i]).sum()) for i, p in enumerate(OSPA_ORDERS)}
        return {"sources": {name: s.to_json() for name, s in self.sources.items()}, "far": self.far,
                "far_vap": self.far_vap, "mota": self.mota, "ospa_deg": self.ospa_deg, "ospa_stamps": defined,
                "stamps": self.n_stamps}


def _latency(times: np.ndarray, first: int, missed: np.ndarray, mode: str) -> float:
    """Track latency of one period (``missed``: its stamps; ``first``: its first stamp's index)."""
    if mode == "official":
        # As released: the time of the k-th stamp of the recording, with k the position of the
        # period's first missed stamp (counted from 1); 0 without a miss.
        return float(times[int(np.argmax(missed))] - times[0]) if missed.any() else 0.0
    detected = ~missed
    return float(times[first + int(np.argmax(detected))] - times[first]) if detected.any() else math.nan


def _source_measures(times: np.ndarray, scores: StampScores, vad: np.ndarray, s: int, mode: str,
                     single: bool) -> SourceMeasures:
    out = SourceMeasures()
    latency, swap_rate, frag_rate = [], [], []
    for first, last in voice_periods(vad[s], mode):
        span = slice(first, last + 1)  # no stamps when first > last (official pairing)
        duration = float(times[last] - times[first])
        out.periods_s.append((float(times[first]), float(times[last])))
        out.az_error_deg.append(math.degrees(_mean(scores.az_error[s, span])))
        out.inc_error_deg.append(math.degrees(_mean(scores.inc_error[s, span])))
        ungated = _mean(scores.az_distance[s, :, span]) if single else math.nan
        out.az_error_ungated_deg.append(math.degrees(ungated))
        if mode == "official":  # as released: the ungated inclination error holds the azimuth distance
            out.inc_error_ungated_deg.append(math.degrees(ungated))
        else:
            out.inc_error_ungated_deg.append(math.degrees(_mean(scores.inc_distance[s, :, span])) if single
                                             else math.nan)
        missed = scores.missed[s, span]
        out.pd.append(float(1.0 - missed.mean()) if missed.size else math.nan)
        latency.append(_latency(times, first, missed, mode))
        swaps = int(scores.swaps[s, span].sum())
        swap_rate.append(_rate(swaps, duration))
        recovered = int((missed[:-1] & ~missed[1:]).sum())
        frag_rate.append(_rate(recovered + swaps, duration))
    out.latency_s, out.swap_rate, out.frag_rate = _mean(latency), _mean(swap_rate), _mean(frag_rate)
    out.swaps = int((scores.swaps[s] & vad[s]).sum())
    return out


def recording_measures(times: np.ndarray, truth_az: np.ndarray, truth_inc: np.ndarray, vad: np.ndarray,
                       est_az: np.ndarray, est_inc: np.ndarray, mode: str = "official",
                       source_names: Sequence[str] | None = None, label: str = "recording") -> RecordingMeasures:
    """Every measure of one recording (shapes in the module docstring; ``times`` ``(T,)`` seconds).

    ``label`` names the recording in the warnings about measures with nothing to average."""
    times = np.asarray(times, np.float64)
    vad = np.asarray(vad).astype(bool)
    scores = score_stamps(truth_az, truth_inc, vad, est_az, est_inc, mode)
    if times.shape != (vad.shape[1],):
        raise InputError(f"LOCATA stamps: {times.shape[0]} times for {vad.shape[1]} stamps")
    names = list(source_names) if source_names is not None else [f"source{s + 1}" for s in range(vad.shape[0])]
    single = vad.shape[0] == 1
    sources = {}
    for s, name in enumerate(names):
        sources[name] = _source_measures(times, scores, vad, s, mode, single)
        if not sources[name].pd:
            warnings.warn(f"{label}: source {name} has no voice-active period on the scored stamps ({mode} "
                          "periods); its per-period measures are empty and its latency and rates NaN")
    span = float(times[-1] - times[0]) if times.size else 0.0
    far = _rate(int(scores.false.sum()), span)
    union = voice_periods(vad.any(0), mode)
    far_vap = _mean([_rate(int(scores.false[a:b + 1].sum()), float(times[b] - times[a])) for a, b in union])
    if not union:
        warnings.warn(f"{label}: no voice-active period on the scored stamps ({mode} periods); FAR during "
                      "voice activity is NaN")
    mota = [float((scores.false.sum() + scores.missed[s].sum() + scores.swaps[s].sum()) / max(len(names), 1))
            for s in range(len(names))]
    ospa = {ospa_key(p): _mean(scores.ospa[i]) for i, p in enumerate(OSPA_ORDERS)}
    return RecordingMeasures(mode, sources, far, far_vap, mota, ospa, scores, int(times.size))


# -- over a task -------------------------------------------------------------------------------
PERIOD_MEASURES = ("az_error_deg", "az_error_ungated_deg", "inc_error_deg", "inc_error_ungated_deg", "pd")
SOURCE_MEASURES = ("latency_s", "swap_rate", "frag_rate")


def _as_json(recording: RecordingMeasures | Mapping[str, Any]) -> Mapping[str, Any]:
    return recording.to_json() if isinstance(recording, RecordingMeasures) else recording


def task_averages(recordings: Sequence[RecordingMeasures | Mapping[str, Any]]) -> dict[str, Any]:
    """The challenge's task averages of some recordings (:class:`RecordingMeasures` or their
    ``to_json()``): period measures pooled over every period of every source and recording;
    latency, swap and fragmentation rates over (recording, source) values; FAR and FAR during
    voice activity over recordings; OSPA over every stamp where it is defined; swaps summed; MOTA
    over (recording, source) values. NaN (or None) values are left out of every mean."""
    recs = [_as_json(r) for r in recordings]
    sources = [s for r in recs for s in r["sources"].values()]
    out: dict[str, Any] = {}
    for name in PERIOD_MEASURES:
        out[name] = _mean([v for s in sources for v in s[name]])
    for name in SOURCE_MEASURES:
        out[name] = _mean([s[name] for s in sources])
    out["far"] = _mean([r["far"] for r in recs])
    out["far_vap"] = _mean([r["far_vap"] for r in recs])
    out["mota"] = _mean([v for r in recs for v in r["mota"]])
    out["swaps"] = int(sum(s["swaps"] for s in sources))
    out["ospa_deg"] = {}
    for p in OSPA_ORDERS:
        key = ospa_key(p)
        weights = [(r["ospa_deg"][key], r["ospa_stamps"][key]) for r in recs if r["ospa_stamps"][key]]
        total = sum(n for _, n in weights)
        out["ospa_deg"][key] = float(sum(v * n for v, n in weights) / total) if total else math.nan
    return out
