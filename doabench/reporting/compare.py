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

This module composes the parts and decides the verdicts: :mod:`doabench.reporting.pairing` pairs
the episodes, :mod:`doabench.metrics.pooled` defines the statistics and
:mod:`doabench.metrics.paired` draws their paired bootstrap, :mod:`doabench.reporting.silence`
adds the statistics by frames since voice; :mod:`doabench.reporting.compare_report` renders the
comparisons as Markdown, CSV and a forest plot.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from doabench.errors import InputError
from doabench.metrics import MIN_STRATUM, Metric, bootstrap_strata, paired_difference, summary_metrics
from doabench.reporting.pairing import Pairing, Run, pair
from doabench.reporting.silence import silence_metrics, voiced_errors

N_RESAMPLES = 2000
LEVEL = 0.95
#: verdict words (for the run named first, against the other)
BETTER, WORSE, TIE = "better", "worse", "no significant difference"
#: what a line backed by fewer than ``MIN_EPISODES`` contributing episodes says instead of a verdict
TOO_FEW = "too few episodes"
MIN_EPISODES = 5
#: the CSV's ``bootstrap`` column: drawn within each grid cell, or across the episodes of the line's scope
STRATIFIED, ACROSS = "within cells", "across episodes"


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


def compare_scope(p: Pairing, metric: Metric, positions: np.ndarray, strata: Sequence[np.ndarray], scope: str,
                  n_resamples: int, seed: int, min_episodes: int = MIN_EPISODES) -> Row:
    """The paired difference ``a - b`` of ``metric`` over the episodes at ``positions``
    (:func:`doabench.metrics.paired_difference`), drawn within ``strata`` (positions among them)."""
    rows_a = [p.rows_a[i] for i in positions]
    rows_b = [p.rows_b[i] for i in positions]
    fa = [p.frames_a[i] for i in positions] if p.frames_a is not None else None
    fb = [p.frames_b[i] for i in positions] if p.frames_b is not None else None
    d = paired_difference(metric, rows_a, rows_b, fa, fb, strata, n_resamples, seed, LEVEL)
    first = rows_a[0] if rows_a else {}
    cell = scope != "pooled"
    return Row(scope, first.get("t60") if cell else None, first.get("snr") if cell else None, len(positions), metric,
               metric.scale * d.a, metric.scale * d.b, metric.scale * (d.a - d.b),
               metric.scale * d.low, metric.scale * d.high,
               n_contributing=d.n_contributing, min_episodes=min_episodes,
               bootstrap=STRATIFIED if d.stratified else ACROSS)


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
    metrics = summary_metrics(p.rows_a, p.rows_b, recordings, voiced_errors if frames else None)
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
