"""Paired comparison of results files: is one run better than another on the same episodes?

``doabench compare A.json B.json [C.json ...]`` compares run A with each other run over the
episodes both ran (same task, same task version, same episode seeds). The two runs saw the same
rooms, trajectories and speech, so what makes an episode hard for both cancels in the difference,
and the interval of the difference is narrower than the two runs' own intervals suggest.

The interval is a stratified paired bootstrap over episodes (the model is ``rliable``'s stratified
bootstrap, Agarwal et al., NeurIPS 2021): every resample draws, within each grid cell, as many
episodes as the cell holds, with replacement, and the same episodes for both runs; the statistic
(a pooled RMSAE, a mean, a quantile, the pooled lag) is recomputed from the drawn episodes, and the
2.5th and 97.5th percentiles of the difference are its 95 % interval (percentile method). A
difference whose interval excludes 0 is called better or worse; otherwise "no significant
difference". Per cell, the bootstrap draws from that cell only.

Strata of one or two episodes: a cell of one paired episode gives that episode in every resample,
so a bootstrap stratified by such cells has an interval of no width (twelve cells of one episode
each: ``-12.20 [-12.20, -12.20]``). The pooled lines are therefore stratified only when every cell
holds at least :data:`doabench.metrics.MIN_STRATUM` (5) paired episodes; otherwise the episodes are
drawn across the whole task (:func:`doabench.metrics.bootstrap_strata`), which keeps the spread
between cells in the interval, and a note and the CSV's ``bootstrap`` column say so.

A verdict needs enough episodes behind it: every line says how many paired episodes contribute
to it (``n``: those with frames of it in both runs, e.g. frames in a speed band, or a moving
talker for the lag), and a line with fewer than ``MIN_EPISODES`` (5) gets "too few episodes"
instead of better, worse or a tie. With one contributing episode every resample holds the same
value and the interval has no width (``+1.35 [+1.35, +1.35]``), which is no evidence at all.

Every statistic is computed from the per-episode rows of the results files and is exactly the
pooled value of the leaderboards (a pooled RMS is ``sqrt(sum n_i rms_i^2 / sum n_i)``; a mean over
non-silent frames weights episodes by their non-silent frames; the lag minimises the pooled lag
curve and is undefined where the estimates do not follow the talker,
:func:`doabench.metrics.lag_from_curves`). Median and 90th percentile, and the breakdown by
frames since the last voice-active frame (``silence``), need the per-frame estimates (results
written without ``--no-frames``).
"""
from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from doabench.errors import InputError
from doabench.results.schema import load_results, summary_problem
from doabench.results.identity import results_task_options
from doabench.results.labels import csv_cell, inert_texts, run_label
from doabench.metrics import (LAG_MAX_S, LAG_STEP_S, MIN_STRATUM, THRESHOLDS_DEG, bootstrap_counts, bootstrap_strata,
                              follows, lag_grid, moves, score_frames)

N_RESAMPLES = 2000
LEVEL = 0.95
#: runs of frames since the last voice-active frame, ``[low, high)`` (high None: no bound)
SILENCE_BUCKETS = ((1, 3), (3, 6), (6, 11), (11, 21), (21, 31), (31, 41), (41, None))
#: verdict words (for the run named first, against the other)
BETTER, WORSE, TIE = "better", "worse", "no significant difference"
#: what a line backed by fewer than ``MIN_EPISODES`` contributing episodes says instead of a verdict
TOO_FEW = "too few episodes"
MIN_EPISODES = 5
#: the CSV's ``bootstrap`` column: drawn within each grid cell, or across the episodes of the line's scope
STRATIFIED, ACROSS = "within cells", "across episodes"


# -- loading and pairing ------------------------------------------------------------------------------------
@dataclass
class Run:
    """A results file as compared: its path, content and the label tables show."""

    path: Path
    results: dict[str, Any]
    label: str = ""

    @property
    def rows(self) -> list[dict[str, Any]]:
        return list(self.results.get("episodes") or [])

    @property
    def task(self) -> dict[str, Any]:
        return self.results.get("task") or {}


def load_run(path: str | Path) -> Run:
    """A results JSON written by ``doabench run``; InputError (one line) otherwise."""
    path = Path(path)
    data = inert_texts(load_results(path))  # its texts are shown, never interpreted (doabench.results.labels)
    if not data.get("episodes"):
        raise InputError(f"{path} has no per-episode rows to pair")
    problem = summary_problem(data)
    if problem:
        raise InputError(f"{path}: {problem}")
    return Run(path, data, run_label(data))


def _distinct_labels(runs: Sequence[Run]) -> None:
    """Runs whose labels coincide (one tracker, two weights or two folders) get the file name too."""
    for run in runs:
        if sum(r.label == run.label for r in runs) > 1:
            run.label = f"{run.label} [{run.path.name}]"
    for i, run in enumerate(runs):
        if sum(r.label == run.label for r in runs) > 1:
            run.label = f"{run.label} #{i + 1}"


@dataclass
class Pairing:
    """The episodes two runs share, in episode order: ``rows_a[i]`` and ``rows_b[i]`` are the same
    episode (same index and seed); ``frames_a``/``frames_b`` their per-frame estimates or None."""

    a: Run
    b: Run
    rows_a: list[dict[str, Any]]
    rows_b: list[dict[str, Any]]
    frames_a: list[dict[str, Any]] | None
    frames_b: list[dict[str, Any]] | None
    cells: dict[str, np.ndarray] = field(default_factory=dict)  # cell id -> positions in the rows

    @property
    def n(self) -> int:
        return len(self.rows_a)


def _frames_by_episode(run: Run) -> dict[int, dict[str, Any]] | None:
    """The run's per-frame estimates by episode index (None without them), each carrying whether
    the run folds directions onto a plane (a planar array), as its scores did."""
    frames = run.results.get("frames")
    if not frames or len(frames) != len(run.rows) or any(f is None for f in frames):
        return None
    planar = bool((run.results.get("scoring") or {}).get("planar_fold"))
    return {int(row["episode"]): {**f, "planar": planar} for row, f in zip(run.rows, frames)}


def pair(a: Run, b: Run, by_seed: bool = False) -> Pairing:
    """The episodes ``a`` and ``b`` share; InputError saying why when they cannot be paired.

    ``by_seed``: pair the episodes of two *tasks* that draw the same scenes (same scene seeds) and
    render them differently, e.g. ``sim-walk`` and ``sim-walk-pra`` (builtin and pyroomacoustics):
    episodes are matched by seed, the cells are ``a``'s."""
    ta, tb = a.task, b.task
    if by_seed:
        return _pair_by_seed(a, b)
    if ta.get("id") != tb.get("id"):
        raise InputError(f"{a.path} is a run of task {ta.get('id')} and {b.path} of task {tb.get('id')}: "
                         "only runs of the same task share episodes")
    if ta.get("version") != tb.get("version"):
        raise InputError(f"{a.path} ran {ta.get('id')} v{ta.get('version')} and {b.path} v{tb.get('version')}: "
                         "different task versions have different episodes")
    over_a, over_b = results_task_options(a.results), results_task_options(b.results)
    if over_a != over_b:  # another simulator, scene overrides, LOCATA split or VAD
        raise InputError(f"{a.path} and {b.path} ran {ta.get('id')} with different task options "
                         f"({json.dumps(over_a, sort_keys=True)} and {json.dumps(over_b, sort_keys=True)}): "
                         "not the same episodes or scoring (--by-seed pairs two renderings of the same scenes)")
    by_b = {int(r["episode"]): r for r in b.rows}
    shared_a, shared_b = [], []
    for row in sorted(a.rows, key=lambda r: int(r["episode"])):
        other = by_b.get(int(row["episode"]))
        if other is None:
            continue
        if row.get("seed") != other.get("seed"):
            raise InputError(f"episode {row['episode']} has seed {row.get('seed')} in {a.path} and "
                             f"{other.get('seed')} in {b.path}: not the same episodes (another base seed or "
                             "simulator?)")
        shared_a.append(row)
        shared_b.append(other)
    if not shared_a:
        raise InputError(f"{a.path} and {b.path} have no episode in common (episodes "
                         f"{_span(a.rows)} and {_span(b.rows)})")
    fa, fb = _frames_by_episode(a), _frames_by_episode(b)
    frames_a = [fa[int(r["episode"])] for r in shared_a] if fa is not None else None
    frames_b = [fb[int(r["episode"])] for r in shared_b] if fb is not None else None
    cells: dict[str, list[int]] = {}
    task_id = str(ta.get("id"))
    for i, row in enumerate(shared_a):
        cell = str(row.get("task") or task_id)
        if cell != task_id:
            cells.setdefault(cell, []).append(i)
    return Pairing(a, b, shared_a, shared_b, frames_a, frames_b,
                   {k: np.asarray(v) for k, v in cells.items()} if len(cells) > 1 else {})


def _pair_by_seed(a: Run, b: Run) -> Pairing:
    by_b = {r.get("seed"): r for r in b.rows if r.get("seed") is not None}
    shared_a = [r for r in sorted(a.rows, key=lambda r: int(r["episode"])) if r.get("seed") in by_b]
    if not shared_a:
        raise InputError(f"{a.path} ({a.task.get('id')}) and {b.path} ({b.task.get('id')}) share no scene seed: "
                         "they are not renderings of the same scenes")
    shared_b = [by_b[r["seed"]] for r in shared_a]
    fa, fb = _frames_by_episode(a), _frames_by_episode(b)
    frames_a = [fa[int(r["episode"])] for r in shared_a] if fa is not None else None
    frames_b = [fb[int(r["episode"])] for r in shared_b] if fb is not None else None
    cells: dict[str, list[int]] = {}
    for i, row in enumerate(shared_a):
        cells.setdefault(str(row.get("task") or a.task.get("id")), []).append(i)
    return Pairing(a, b, shared_a, shared_b, frames_a, frames_b,
                   {k: np.asarray(v) for k, v in cells.items()} if len(cells) > 1 else {})


def _span(rows: Sequence[dict[str, Any]]) -> str:
    idx = sorted(int(r["episode"]) for r in rows)
    return f"{idx[0]}-{idx[-1]}" if idx else "none"


# -- statistics from per-episode sums ----------------------------------------------------------------------
@dataclass(frozen=True)
class Metric:
    """A compared statistic: ``stats(rows, frames) -> (episodes, k)`` per-episode sums, and
    ``value(sums (B, k)) -> (B,)`` the statistic of episodes whose sums were added up. The last
    column of the sums is positive exactly for the episodes that contribute (their frame count)."""

    key: str
    label: str
    unit: str
    higher_is_better: bool
    stats: Callable[[list[dict[str, Any]], list[dict[str, Any]] | None], np.ndarray]
    value: Callable[[np.ndarray], np.ndarray]
    scale: float = 1.0  # shown value = scale * value (fractions as %)
    quantile: float | None = None  # frame quantiles: not a function of sums
    frames: bool = False  # needs per-frame estimates


def _rms(sums: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(sums[:, 0] / sums[:, 1])


def _ratio(sums: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return sums[:, 0] / sums[:, 1]


def _num(row: dict[str, Any], key: str) -> float:
    v = row.get(key)
    return float("nan") if v is None else float(v)


def _rms_stats(metric: str, count: str) -> Callable:
    def stats(rows: list[dict[str, Any]], frames: Any = None) -> np.ndarray:
        rms = np.array([_num(r, metric) for r in rows])
        n = np.array([_num(r, count) for r in rows])
        ok = np.isfinite(rms) & np.isfinite(n) & (n > 0)
        return np.stack([np.where(ok, np.nan_to_num(rms) ** 2 * np.nan_to_num(n), 0.0), np.where(ok, n, 0.0)], 1)
    return stats


def _mean_stats(metric: str, count: str | None) -> Callable:
    def stats(rows: list[dict[str, Any]], frames: Any = None) -> np.ndarray:
        v = np.array([_num(r, metric) for r in rows])
        n = np.ones(len(rows)) if count is None else np.array([_num(r, count) for r in rows])
        ok = np.isfinite(v) & np.isfinite(n) & (n > 0)
        return np.stack([np.where(ok, np.nan_to_num(v) * np.nan_to_num(n), 0.0), np.where(ok, n, 0.0)], 1)
    return stats


def _count_stats(count: str) -> Callable:
    """Frame quantiles are no function of sums: their one column counts each episode's frames."""
    def stats(rows: list[dict[str, Any]], frames: Any = None) -> np.ndarray:
        return np.nan_to_num(np.array([_num(r, count) for r in rows])).reshape(-1, 1)
    return stats


def _lag_stats(rows: list[dict[str, Any]], frames: Any = None) -> np.ndarray:
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
    follow the talker (:func:`doabench.metrics.follows`), as :func:`doabench.metrics.lag_from_curves` decides."""
    curve, const, unrecorded, moving = sums[:, :-3], sums[:, -3], sums[:, -2], sums[:, -1]
    lag = lag_grid(LAG_MAX_S, LAG_STEP_S)[np.argmin(curve, axis=1)]
    return np.where((moving > 0) & follows(curve, np.where(unrecorded > 0, np.nan, const)), lag, np.nan)


def _band_stats(label: str) -> Callable:
    def stats(rows: list[dict[str, Any]], frames: Any = None) -> np.ndarray:
        sums = [(r.get("speed_bands") or {}).get(label) or [0.0, 0] for r in rows]
        return np.array([[float(s), float(n)] for s, n in sums]).reshape(-1, 2)
    return stats


def _has(rows: Sequence[dict[str, Any]], key: str) -> bool:
    return any(r.get(key) is not None for r in rows)


# frame-level statistics (need per-frame estimates) --------------------------------------------------------
def frames_since_voice(vad: np.ndarray) -> np.ndarray:
    """``(T,)`` frames since the last voice-active frame: 0 on one, -1 before the first."""
    vad = np.asarray(vad, bool)
    index = np.arange(len(vad))
    last = np.maximum.accumulate(np.where(vad, index, -1))
    return np.where(last >= 0, index - last, -1)


def _unit(a: Any) -> np.ndarray:
    a = np.asarray(a, np.float64).reshape(-1, 3)
    with np.errstate(invalid="ignore", divide="ignore"):
        return a / np.linalg.norm(a, axis=-1, keepdims=True)


def episode_frames(frame: dict[str, Any], hold: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(errors deg, vad, frames since voice)`` of an episode's scored frames, scored as ``doabench
    run`` scores (:func:`doabench.metrics.score_frames`: invalid truth left out, a planar array's
    directions folded), with the estimates held after ``hold`` silent frames when given (the
    learned trackers' rule)."""
    est, truth = _unit(frame["estimates"]), _unit(frame["truth"])
    vad = np.asarray(frame["vad"], bool).reshape(-1)
    if hold is not None:
        from doabench.trackers.hold import hold_in_silences

        est = hold_in_silences(est, vad, hold)
    scored = score_frames(est, truth, vad, frame.get("valid"), bool(frame.get("planar")))
    return scored.errors, scored.vad, frames_since_voice(vad)[scored.keep]


def _frame_rms_stats(select: Callable[[np.ndarray, np.ndarray], np.ndarray], hold: int | None = None) -> Callable:
    def stats(rows: list[dict[str, Any]], frames: list[dict[str, Any]] | None) -> np.ndarray:
        assert frames is not None
        out = np.zeros((len(frames), 2))
        for i, f in enumerate(frames):
            e, vad, since = episode_frames(f, hold)
            m = select(vad, since)
            out[i] = float(np.square(e[m]).sum()), float(m.sum())
        return out
    return stats


def _voiced_errors(frames: list[dict[str, Any]]) -> tuple[np.ndarray, np.ndarray]:
    """Errors of the voice-active frames and the position of each one's episode."""
    errs, owner = [], []
    for i, f in enumerate(frames):
        e, vad, _ = episode_frames(f)
        errs.append(e[vad])
        owner.append(np.full(int(vad.sum()), i))
    return (np.concatenate(errs) if errs else np.zeros(0)), (np.concatenate(owner) if owner else np.zeros(0, int))


def _weighted_quantile(values: np.ndarray, owner: np.ndarray, counts: np.ndarray, q: float) -> np.ndarray:
    """The ``q`` quantile (inverted CDF) of ``values`` with each value repeated as often as its
    episode was drawn: ``counts`` ``(B, episodes)`` -> ``(B,)``."""
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


# -- the metric list -------------------------------------------------------------------------------------------
def summary_metrics(rows_a: Sequence[dict[str, Any]], rows_b: Sequence[dict[str, Any]], frames: bool,
                    recordings: bool) -> list[Metric]:
    """The metrics both runs' rows carry: RMSAE all frames and voice-active, the other summary
    metrics of the leaderboards, the lag and the RMSAE per angular-speed band where present."""
    out = [Metric("rmsae_all", "RMSAE all frames", "deg", False, _rms_stats("rmsae_all", "n_frames"), _rms),
           Metric("rmsae_nonsilent", "RMSAE voice-active frames", "deg", False,
                  _rms_stats("rmsae_nonsilent", "n_nonsilent"), _rms)]
    if recordings:
        out.append(Metric("rmsae_all_recording_mean", "RMSAE all frames, mean of recordings", "deg", False,
                          _mean_stats("rmsae_all", None), _ratio))
    if all(_has(r, "mae") for r in (rows_a, rows_b)):
        out.append(Metric("mae", "MAE voice-active", "deg", False, _mean_stats("mae", "n_nonsilent"), _ratio))
    if frames:
        out += [Metric("median", "median error voice-active", "deg", False, _count_stats("n_nonsilent"),
                       _ratio, quantile=0.5, frames=True),
                Metric("p90", "90th percentile voice-active", "deg", False, _count_stats("n_nonsilent"),
                       _ratio, quantile=0.9, frames=True)]
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
        from doabench.metrics import SPEED_BANDS

        for label, _, _ in SPEED_BANDS:
            out.append(Metric(f"rmsae_speed_{label}", f"RMSAE voice-active, truth moving {label} deg/s", "deg",
                              False, _band_stats(label), _rms))
    return out


def _since_voice_between(lo: int, hi: int | None) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """Selects the frames ``lo`` to ``hi - 1`` since the last voice-active frame (``lo`` and more when
    ``hi`` is None), from ``(vad, frames since voice)``."""
    return lambda vad, since: (since >= lo) & ((since < hi) if hi else True)


def silence_metrics(holds: Sequence[int] = ()) -> list[Metric]:
    """RMSAE by frames since the last voice-active frame, before and after the first voice, and
    with the estimates held after each of ``holds`` silent frames (all need per-frame estimates)."""
    out = []
    for lo, hi in SILENCE_BUCKETS:
        name = f"{lo}-{hi - 1}" if hi else f"{lo}+"
        out.append(Metric(f"rmsae_since_voice_{name}", f"RMSAE {name} frames after voice", "deg", False,
                          _frame_rms_stats(_since_voice_between(lo, hi)),
                          _rms, frames=True))
    out += [Metric("rmsae_before_first_voice", "RMSAE before the first voice", "deg", False,
                   _frame_rms_stats(lambda v, s: s < 0), _rms, frames=True),
            Metric("rmsae_after_first_voice", "RMSAE after the first voice", "deg", False,
                   _frame_rms_stats(lambda v, s: s >= 0), _rms, frames=True)]
    for hold in holds:
        out.append(Metric(f"rmsae_all_hold_{hold}", f"RMSAE all frames, held after {hold} silent frames", "deg",
                          False, _frame_rms_stats(lambda v, s: np.ones(len(v), bool), hold), _rms, frames=True))
    return out


# -- the compared rows (resampled by doabench.metrics.bootstrap_counts) ------------------------------------
@dataclass(frozen=True)
class Row:
    """One compared statistic in one scope (pooled or a cell)."""

    scope: str
    t60: float | None
    snr: float | None
    n_episodes: int
    metric: Metric
    a: float
    b: float
    diff: float
    low: float
    high: float
    #: paired episodes that contribute to the line in both runs (frames of it), and how many a verdict needs
    n_contributing: int
    min_episodes: int = MIN_EPISODES
    #: how the bootstrap drew: within each grid cell (``STRATIFIED``) or across the scope's episodes (``ACROSS``)
    bootstrap: str = ACROSS

    @property
    def enough(self) -> bool:
        """Enough contributing episodes for a verdict (module docstring)."""
        return self.n_contributing >= self.min_episodes

    @property
    def verdict(self) -> str:
        if not self.enough:
            return TOO_FEW
        if not (math.isfinite(self.low) and math.isfinite(self.high)) or self.low <= 0 <= self.high:
            return TIE
        lower = self.high < 0
        return BETTER if lower != self.metric.higher_is_better else WORSE


def _values(metric: Metric, sums: np.ndarray, frames: list[dict[str, Any]] | None, counts: np.ndarray) -> np.ndarray:
    """The statistic for each row of ``counts`` ``(B, episodes)`` from the episodes' ``sums``
    (``metric.stats``) or, for a frame quantile, their ``frames``."""
    if metric.quantile is not None:
        values, owner = _voiced_errors(frames or [])
        return _weighted_quantile(values, owner, counts, metric.quantile)
    return metric.value(counts @ sums)


def compare_scope(p: Pairing, metric: Metric, positions: np.ndarray, strata: Sequence[np.ndarray], scope: str,
                  n_resamples: int, seed: int, min_episodes: int = MIN_EPISODES) -> Row:
    """The paired difference ``a - b`` of ``metric`` over the episodes at ``positions``."""
    rows_a = [p.rows_a[i] for i in positions]
    rows_b = [p.rows_b[i] for i in positions]
    fa = [p.frames_a[i] for i in positions] if p.frames_a is not None else None
    fb = [p.frames_b[i] for i in positions] if p.frames_b is not None else None
    sums_a, sums_b = metric.stats(rows_a, fa), metric.stats(rows_b, fb)
    ones = np.ones((1, len(positions)))
    if metric.quantile is not None:  # the exact quantile, as the leaderboards compute it
        assert fa is not None and fb is not None, "quantile metrics are compared only with per-frame estimates"
        point = [float(np.percentile(_voiced_errors(f)[0], 100 * metric.quantile))
                 if _voiced_errors(f)[0].size else float("nan") for f in (fa, fb)]
    else:
        point = [float(_values(metric, s, f, ones)[0]) for s, f in ((sums_a, fa), (sums_b, fb))]
    strata, stratified = bootstrap_strata(strata, len(positions))
    counts = bootstrap_counts(strata, len(positions), n_resamples, seed)
    diffs = _values(metric, sums_a, fa, counts) - _values(metric, sums_b, fb, counts)
    diffs = diffs[np.isfinite(diffs)]
    low, high = (np.percentile(diffs, [(1 - LEVEL) / 2 * 100, (1 + LEVEL) / 2 * 100]) if diffs.size
                 else (float("nan"), float("nan")))
    first = rows_a[0] if rows_a else {}
    cell = scope != "pooled"
    return Row(scope, first.get("t60") if cell else None, first.get("snr") if cell else None, len(positions), metric,
               metric.scale * point[0], metric.scale * point[1], metric.scale * (point[0] - point[1]),
               metric.scale * float(low), metric.scale * float(high),
               n_contributing=int(np.sum((sums_a[:, -1] > 0) & (sums_b[:, -1] > 0))), min_episodes=min_episodes,
               bootstrap=STRATIFIED if stratified else ACROSS)


@dataclass
class Comparison:
    """Run ``a`` against run ``b``: the pooled rows and, for a grid task, the rows of every cell."""

    pairing: Pairing
    pooled: list[Row]
    cells: list[Row]
    notes: list[str]


def compare(a: Run, b: Run, silence: bool = False, holds: Sequence[int] = (), n_resamples: int = N_RESAMPLES,
            seed: int = 0, only: Sequence[str] | None = None, by_seed: bool = False,
            min_episodes: int = MIN_EPISODES) -> Comparison:
    """Pair ``a`` and ``b`` (by scene seed across two tasks with ``by_seed``) and compare every
    metric both carry (or those named in ``only``), pooled and per cell; a line with fewer than
    ``min_episodes`` contributing episodes gets no verdict."""
    p = pair(a, b, by_seed)
    frames = p.frames_a is not None and p.frames_b is not None
    notes = []
    if (silence or holds) and not frames:
        missing = [str(r.path) for r, f in ((a, p.frames_a), (b, p.frames_b)) if f is None]
        raise InputError(f"--silence and --hold need per-frame estimates, which {', '.join(missing)} lacks "
                         "(written with --no-frames); run it again without --no-frames")
    if not frames:
        notes.append("median and p90 need per-frame estimates (results written without --no-frames)")
    recordings = all(r.get("recording") is not None for r in p.rows_a)
    metrics = summary_metrics(p.rows_a, p.rows_b, frames, recordings)
    if frames and (silence or holds):
        metrics += silence_metrics(holds)
    if only is not None:
        metrics = [m for m in metrics if m.key in only]
    everything = np.arange(p.n)
    strata = list(p.cells.values()) or [everything]
    pooled = [compare_scope(p, m, everything, strata, "pooled", n_resamples, seed, min_episodes) for m in metrics]
    if p.cells and not bootstrap_strata(strata, p.n)[1]:
        notes.append(f"the pooled intervals draw episodes across the whole task, not within each cell: a cell holds "
                     f"fewer than {MIN_STRATUM} paired episodes ({min(len(v) for v in p.cells.values())}), and a "
                     "draw within it would repeat the same episodes in every resample")
    cells = []
    for cell, positions in sorted(p.cells.items(), key=lambda kv: (_f(p.rows_a[kv[1][0]].get("t60")),
                                                                   _f(p.rows_a[kv[1][0]].get("snr")), kv[0])):
        cells += [compare_scope(p, m, positions, [np.arange(len(positions))], cell, n_resamples, seed, min_episodes)
                  for m in metrics]
    return Comparison(p, pooled, cells, notes)


def _f(x: Any) -> float:
    return float("inf") if x is None else float(x)


# -- the silence breakdown of one run ----------------------------------------------------------------------------
def silence_breakdown(frames: Sequence[dict[str, Any]]) -> list[tuple[str, int, float, float]]:
    """``(rows label, frames, RMSAE deg, share of the squared error)`` by frames since the last
    voice-active frame, then before and after the first voice."""
    parts = [episode_frames(f) for f in frames]
    e = np.concatenate([x[0] for x in parts]) if parts else np.zeros(0)
    since = np.concatenate([x[2] for x in parts]) if parts else np.zeros(0, int)
    total = float(np.square(e).sum())
    groups = [("0 (voice-active)", since == 0)]
    groups += [(f"{lo}-{hi - 1}" if hi else f"{lo} and more", (since >= lo) & ((since < hi) if hi else True))
               for lo, hi in SILENCE_BUCKETS]
    groups += [("before the first voice", since < 0), ("after the first voice (all but the row above)", since >= 0)]
    out = []
    for label, m in groups:
        sq = float(np.square(e[m]).sum())
        out.append((label, int(m.sum()), math.sqrt(sq / m.sum()) if m.sum() else float("nan"),
                    sq / total if total else float("nan")))
    return out


def held_rmsae(frames: Sequence[dict[str, Any]], hold: int) -> float:
    """RMSAE over all frames of the estimates held after ``hold`` silent frames (the learned
    trackers' rule, ``doabench.hold_in_silences``)."""
    errors = [episode_frames(f, hold)[0] for f in frames]
    e = np.concatenate(errors) if errors else np.zeros(0)
    return float(np.sqrt(np.mean(np.square(e)))) if e.size else float("nan")


def hold_the_truth(frames: Sequence[dict[str, Any]]) -> float:
    """RMSAE over all frames of an oracle that knows the true direction of every voice-active
    frame and holds the last one through silent frames (90° before the first voice-active frame),
    scored as the runs are: what any tracker that holds its last direction can reach on these
    episodes."""
    sq, n = 0.0, 0
    for f in frames:
        truth = _unit(f["truth"])
        vad = np.asarray(f["vad"], bool).reshape(-1)
        last = np.maximum.accumulate(np.where(vad, np.arange(len(vad)), -1))
        scored = score_frames(truth[np.maximum(last, 0)], truth, vad, f.get("valid"), bool(f.get("planar")))
        err = np.where((last < 0)[scored.keep], 90.0, scored.errors)
        sq += float(np.square(err).sum())
        n += err.size
    return math.sqrt(sq / n) if n else float("nan")


# -- output ----------------------------------------------------------------------------------------------------
DEFAULT_CELL_METRICS = ("rmsae_all", "rmsae_nonsilent", "lag_s")


def _fmt(x: float, unit: str, signed: bool = False) -> str:
    if x is None or not math.isfinite(x):
        return "—"
    digits = 2
    return f"{x:+.{digits}f}" if signed else f"{x:.{digits}f}"


def _diff_text(row: Row) -> str:
    """The difference and its interval; without the interval where too few episodes back it (an
    interval of one or two episodes reads as a certainty it is not)."""
    u = row.metric.unit
    interval = "" if not (row.enough and math.isfinite(row.low) and math.isfinite(row.high)) else \
        f" [{_fmt(row.low, u, True)}, {_fmt(row.high, u, True)}]"
    return _fmt(row.diff, u, True) + interval


def _metric_text(m: Metric) -> str:
    return f"{m.label} ({m.unit})"


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    cell = lambda s: str(s).replace("|", "\\|")  # noqa: E731
    return ["| " + " | ".join(cell(h) for h in header) + " |", "|" + "---|" * len(header)] + \
           ["| " + " | ".join(cell(c) for c in r) + " |" for r in rows]


def cell_summary(c: Comparison, metric: str = "rmsae_all") -> str:
    """``better in 3, worse in 12, no significant difference in 3 of 18 cells`` (``, too few episodes
    in 2`` before ``of`` where some cells have too few; empty without cells)."""
    rows = [r for r in c.cells if r.metric.key == metric]
    if not rows:
        return ""
    n = {v: sum(r.verdict == v for r in rows) for v in (BETTER, WORSE, TIE, TOO_FEW)}
    too_few = f", {TOO_FEW} in {n[TOO_FEW]}" if n[TOO_FEW] else ""
    return (f"better in {n[BETTER]}, worse in {n[WORSE]}, no significant difference in {n[TIE]}{too_few} "
            f"of {len(rows)} cells")


def markdown(comparisons: Sequence[Comparison], cell_metrics: Sequence[str] = DEFAULT_CELL_METRICS,
             breakdowns: Sequence[tuple[Run, list, float, dict[int, float]]] = (),
             n_resamples: int = N_RESAMPLES) -> str:
    """The report: per comparison a pooled table, a per-cell table (grid tasks), the notes; then
    the silence breakdown of each run (``breakdowns``: run, :func:`silence_breakdown`, the
    hold-the-truth oracle, :func:`held_rmsae` per hold)."""
    lines = ["# doabench compare", ""]
    if comparisons:
        lines += [f"Paired over the episodes both runs ran (same task version and seeds). Difference = first run − "
                  f"other run; brackets: 95 % interval of a paired bootstrap over episodes ({n_resamples} resamples, "
                  f"stratified by grid cell where every cell holds at least {MIN_STRATUM} paired episodes, else "
                  "drawn across the task). Verdict for the first run: *better* or *worse* when the interval "
                  "excludes 0 (lower is better, except the shares within N°), else *no significant difference*; "
                  f"*{TOO_FEW}* (no verdict, no interval) where fewer than {_min_episodes(comparisons)} paired "
                  "episodes contribute to the line. n: the paired episodes that contribute (frames of that speed "
                  "band, a moving talker for the lag).", ""]
    for c in comparisons:
        p = c.pairing
        a, b = p.a, p.b
        task = a.task
        total_a, total_b = len(a.rows), len(b.rows)
        lines += [f"## `{a.label}` against `{b.label}`", "",
                  f"Task `{task.get('id')}` v{task.get('version')}; {p.n} episodes in common"
                  + (f" (of {total_a} and {total_b})" if (total_a, total_b) != (p.n, p.n) else "")
                  + f". Files: `{a.path}`, `{b.path}`.", ""]
        headline = next((r for r in c.pooled if r.metric.key == "rmsae_all"), None)
        if headline is not None:
            summary = cell_summary(c)
            lines += [f"**RMSAE all frames: {_diff_text(headline)} deg, {headline.verdict}**"
                      + (f" ({summary}: RMSAE all frames)" if summary else "") + ".", ""]
        lines += _table(["metric", "n", f"`{a.label}`", f"`{b.label}`", "difference [95% CI]", "verdict"],
                        [[_metric_text(r.metric), str(r.n_contributing), _fmt(r.a, r.metric.unit),
                          _fmt(r.b, r.metric.unit), _diff_text(r), r.verdict] for r in c.pooled])
        shown = [key for key in cell_metrics if any(r.metric.key == key for r in c.cells)]
        if shown:
            by_cell: dict[str, dict[str, Row]] = {}
            for r in c.cells:
                by_cell.setdefault(r.scope, {})[r.metric.key] = r
            header = ["cell", "episodes"]
            for key in shown:
                m = next(r.metric for r in c.cells if r.metric.key == key)
                header += [f"{_metric_text(m)}: first / other", "difference [95% CI], verdict"]
            table = []
            for scope, metrics in by_cell.items():
                first = next(iter(metrics.values()))
                row = [f"`{scope}`" + (f" (T60 {_g(first.t60)} s, SNR {_g(first.snr)} dB)" if first.t60 is not None
                                       else ""), str(first.n_episodes)]
                for key in shown:
                    cell = metrics.get(key)
                    row += ["—", "—"] if cell is None else [
                        f"{_fmt(cell.a, cell.metric.unit)} / {_fmt(cell.b, cell.metric.unit)}",
                        f"{_diff_text(cell)}, {cell.verdict}"
                        + (f" (n {cell.n_contributing})" if cell.n_contributing != cell.n_episodes else "")]
                table.append(row)
            lines += ["", "### Per cell", ""] + _table(header, table)
        for note in c.notes:
            lines += ["", f"Note: {note}."]
        lines.append("")
    for run, by_silence, oracle, held in breakdowns:
        lines += [f"## Where the error of `{run.label}` is: frames since the last voice-active frame", "",
                  f"`{run.path}`, {run.task.get('id')} v{run.task.get('version')}"
                  f"{'' if not comparisons else ', over the episodes compared above'}.", ""]
        lines += _table(["frames since voice", "frames", "RMSAE (deg)", "share of the squared error"],
                        [[label, f"{n:,}", _fmt(rms, "deg"), _fmt(share, "")] for label, n, rms, share in by_silence])
        lines += ["", f"Hold-the-truth oracle (the true direction of the last voice-active frame, 90° before the first): "
                      f"RMSAE all frames {_fmt(oracle, 'deg')} deg.", ""]
        lines += [f"Held after {h} silent frames: RMSAE all frames {_fmt(v, 'deg')} deg." for h, v in held.items()]
        lines += [""] if held else []
    return "\n".join(lines).rstrip() + "\n"


def _g(x: Any) -> str:
    return "" if x is None else f"{float(x):g}"


def _min_episodes(comparisons: Sequence[Comparison]) -> int:
    """The contributing episodes a verdict needed in these comparisons."""
    return next((r.min_episodes for c in comparisons for r in c.pooled + c.cells), MIN_EPISODES)


CSV_COLUMNS = ("first_file", "other_file", "first", "other", "task", "task_version", "scope", "t60", "snr",
               "n_episodes", "n_contributing", "metric", "unit", "first_value", "other_value", "difference",
               "ci95_low", "ci95_high", "verdict", "bootstrap")


def csv_text(comparisons: Sequence[Comparison]) -> str:
    """Every row of every comparison (pooled first, then the cells), long format."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(CSV_COLUMNS), lineterminator="\n")
    writer.writeheader()
    num = lambda x: "" if x is None or not math.isfinite(float(x)) else f"{float(x):.4f}"  # noqa: E731
    for c in comparisons:
        p = c.pairing
        for r in c.pooled + c.cells:
            row = {"first_file": str(p.a.path), "other_file": str(p.b.path), "first": p.a.label,
                   "other": p.b.label, "task": p.a.task.get("id"), "task_version": p.a.task.get("version"),
                   "scope": r.scope, "t60": _g(r.t60), "snr": _g(r.snr), "n_episodes": r.n_episodes,
                   "n_contributing": r.n_contributing,
                   "metric": r.metric.key, "unit": r.metric.unit, "first_value": num(r.a),
                   "other_value": num(r.b), "difference": num(r.diff), "ci95_low": num(r.low),
                   "ci95_high": num(r.high), "verdict": r.verdict, "bootstrap": r.bootstrap}
            writer.writerow({k: csv_cell(v) for k, v in row.items()})
    return buf.getvalue()


VERDICT_COLOURS = {BETTER: "tab:green", WORSE: "tab:red", TIE: "0.45"}
#: a line without a verdict: a hollow light-grey marker, no interval
NO_VERDICT_COLOUR = "0.65"


def _forest_point(ax: Any, r: Row, y: float, marker: str) -> None:
    """One line of the forest plot: the difference with its interval in its verdict's colour, or
    a hollow marker alone where too few episodes back it (no verdict, no interval to trust)."""
    if not r.enough:
        ax.plot([r.diff], [y], marker=marker, linestyle="none", markersize=5, markerfacecolor="none",
                color=NO_VERDICT_COLOUR)
        return
    colour = VERDICT_COLOURS[r.verdict]
    ax.errorbar([r.diff], [y], xerr=[[r.diff - r.low], [r.high - r.diff]], fmt=marker, color=colour, ecolor=colour,
                capsize=2, markersize=5)


def forest_figure(comparisons: Sequence[Comparison], metrics: Sequence[str] = ("rmsae_all", "rmsae_nonsilent")):
    """A forest plot: per metric a panel, per scope (pooled, then each cell) a row, the paired
    difference as a dot with its 95 % interval, coloured by verdict; one marker per comparison."""
    import matplotlib

    matplotlib.use("Agg")  # files only; never needs a display
    import matplotlib.pyplot as plt

    scopes = ["pooled"] + list(dict.fromkeys(r.scope for c in comparisons for r in c.cells))
    names = {"pooled": "pooled (all episodes)"}
    for c in comparisons:
        for r in c.cells:
            names[r.scope] = f"T60 {_g(r.t60)} s, SNR {_g(r.snr)} dB" if r.t60 is not None else r.scope
    metrics = [m for m in metrics if any(r.metric.key == m for c in comparisons for r in c.pooled)]
    fig, axes = plt.subplots(1, len(metrics), figsize=(4.2 * len(metrics) + 1.5, 0.32 * len(scopes) + 1.6),
                             sharey=True, squeeze=False)
    markers = ("o", "s", "^", "D", "v", "P", "X", "*")
    k = len(comparisons)
    for ax, key in zip(axes[0], metrics):
        for j, c in enumerate(comparisons):
            offset = (j - (k - 1) / 2) * (0.6 / max(k, 1))
            for r in c.pooled + c.cells:
                if r.metric.key != key:
                    continue
                _forest_point(ax, r, scopes.index(r.scope) + offset, markers[j % len(markers)])
        ax.axvline(0.0, color="k", linewidth=0.8)
        ax.axhline(0.5, color="0.8", linewidth=0.8)
        m = next(r.metric for c in comparisons for r in c.pooled if r.metric.key == key)
        ax.set_xlabel(f"{m.label}: difference [{m.unit}]")
        ax.grid(True, axis="x", alpha=0.3)
    axes[0][0].set_yticks(range(len(scopes)))
    axes[0][0].set_yticklabels([names[s] for s in scopes])
    axes[0][0].invert_yaxis()
    first = comparisons[0].pairing.a
    if k > 1:  # the legend tells the comparisons apart by marker; colours are verdicts
        from matplotlib.lines import Line2D

        handles = [Line2D([], [], color="k", marker=markers[j % len(markers)], linestyle="none")
                   for j in range(k)]
        axes[0][-1].legend(handles, [f"vs {c.pairing.b.label}" for c in comparisons], fontsize="small",
                           loc="upper left", bbox_to_anchor=(1.02, 1.0))
    too_few = any(not r.enough for c in comparisons for r in c.pooled + c.cells if r.metric.key in metrics)
    across = any(c.cells and r.bootstrap == ACROSS for c in comparisons for r in c.pooled)
    fig.suptitle(f"{first.label} minus {'each other run' if k > 1 else comparisons[0].pairing.b.label} on "
                 f"{first.task.get('id')} (95% paired bootstrap"
                 f"{f', pooled row drawn across cells: a cell holds fewer than {MIN_STRATUM}' if across else ''}; "
                 f"green better, red worse, grey no significant "
                 f"difference{'; hollow: ' + TOO_FEW if too_few else ''})", fontsize="medium")
    fig.tight_layout()
    return fig


def plot_forest(comparisons: Sequence[Comparison], out: str | Path) -> list[Path]:
    """:func:`forest_figure` written as PNG and PDF."""
    from doabench.reporting.plots import save_figure

    return save_figure(forest_figure(comparisons), out)
