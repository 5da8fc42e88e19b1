"""The report of ``doabench compare``: Markdown, CSV and the forest plot of its comparisons
(:class:`doabench.reporting.compare.Comparison`).

Every line shows the first run's value, the other's, their difference with its 95 % interval and
the verdict (:class:`doabench.reporting.compare.Row`); a line backed by too few episodes shows no
interval (its verdict says so) and is a hollow grey marker in the forest plot. The silence
breakdowns of :mod:`doabench.reporting.silence` follow the comparisons in the Markdown.
"""
from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Any, Sequence

from doabench.metrics import MIN_STRATUM, Metric
from doabench.reporting.compare import (ACROSS, BETTER, MIN_EPISODES, N_RESAMPLES, TIE, TOO_FEW, WORSE, Comparison,
                                       Row)
from doabench.reporting.pairing import Run
from doabench.results.labels import csv_cell

DEFAULT_CELL_METRICS = ("rmsae_all", "rmsae_nonsilent", "lag_s")


def _fmt(x: float, unit: str, signed: bool = False) -> str:
    if x is None or not math.isfinite(x):
        return "—"
    digits = 2
    return f"{x:+.{digits}f}" if signed else f"{x:.{digits}f}"


def diff_text(row: Row) -> str:
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
             breakdowns: Sequence[tuple[Run, list[tuple[str, int, float, float]], float, dict[int, float]]] = (),
             n_resamples: int = N_RESAMPLES) -> str:
    """The report: per comparison a pooled table, a per-cell table (grid tasks), the notes; then
    the silence breakdown of each run (``breakdowns``: run,
    :func:`doabench.reporting.silence.silence_breakdown`, the hold-the-truth oracle
    :func:`~doabench.reporting.silence.hold_the_truth`, :func:`~doabench.reporting.silence.held_rmsae`
    per hold)."""
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
            lines += [f"**RMSAE all frames: {diff_text(headline)} deg, {headline.verdict}**"
                      + (f" ({summary}: RMSAE all frames)" if summary else "") + ".", ""]
        lines += _table(["metric", "n", f"`{a.label}`", f"`{b.label}`", "difference [95% CI]", "verdict"],
                        [[_metric_text(r.metric), str(r.n_contributing), _fmt(r.a, r.metric.unit),
                          _fmt(r.b, r.metric.unit), diff_text(r), r.verdict] for r in c.pooled])
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
                        f"{diff_text(cell)}, {cell.verdict}"
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


def forest_figure(comparisons: Sequence[Comparison], metrics: Sequence[str] = ("rmsae_all", "rmsae_nonsilent")) -> Any:
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
