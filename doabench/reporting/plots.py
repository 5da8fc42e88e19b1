"""The paper's figures from doabench results: RMSAE versus T60 (Figs. 6 and 8), one episode's
track (Fig. 7), SRP-PHAT maps at several resolutions (Figs. 1 and 2), training curves, and the
RMSAE by angular speed of the truth.

Every ``plot_*`` function builds a matplotlib figure (``*_figure``, which tests inspect) and
writes it as PNG and PDF next to each other with atomic writes (:func:`save_figure`); the PNG
carries the fingerprint of what the figure shows (:mod:`doabench.reporting.figure_content`), so a
check can tell whether a committed figure is what its command draws now. Lines of several runs
take :func:`line_styles` (16 distinct colours, then colour, marker and dash never all alike) and
:func:`run_labels` (tracker id with its options and weights); legends sit outside the data, in a
cell of their own where the panels make a grid. Angles are plotted in degrees with doabench's
conventions: elevation is the inclination from +z in ``[0, 180]``, azimuth ``atan2(y, x)`` in
``[-180, 180)``.
"""
from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence, TypedDict

import numpy as np

from doabench.errors import InputError
from doabench.results.identity import results_delays
from doabench.results.labels import run_label

METRICS = ("rmsae_all", "rmsae_nonsilent")
METRIC_LABELS = {"rmsae_all": "RMSAE, all frames [deg]", "rmsae_nonsilent": "RMSAE, non-silent frames [deg]"}
FORMATS = ("png", "pdf")
#: resolution of the PNGs :func:`save_figure` writes
FIGURE_DPI = 110
#: the width of a page the figures are read on, in inches at :data:`FIGURE_DPI` (1280 pixels)
PAGE_WIDTH_IN = 1280 / FIGURE_DPI


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")  # files only; never needs a display
    import matplotlib.pyplot as plt

    return plt


def output_paths(out: str | Path) -> list[Path]:
    """``fig`` or ``fig.png`` -> ``[fig.png, fig.pdf]``."""
    out = Path(out)
    stem = out.with_suffix("") if out.suffix.lower() in (".png", ".pdf") else out
    return [stem.with_name(f"{stem.name}.{ext}") for ext in FORMATS]


def save_figure(fig, out: str | Path, dpi: int = FIGURE_DPI) -> list[Path]:
    """Write ``fig`` as PNG and PDF atomically; returns the paths. Dates are left out of the PDF
    metadata so re-plotting the same data gives the same file. The PNG holds the fingerprint of
    what the figure shows under ``doabench:content`` (a PNG text chunk;
    :func:`doabench.reporting.figure_content.png_fingerprint` reads it back)."""
    from doabench.files import atomic_path
    from doabench.reporting.figure_content import CONTENT_KEY, content_fingerprint

    fingerprint = content_fingerprint(fig)  # from the figure object, before any rendering
    paths = output_paths(out)
    for path in paths:
        with atomic_path(path) as tmp:
            meta = {"CreationDate": None} if path.suffix == ".pdf" else {"Software": None, CONTENT_KEY: fingerprint}
            fig.savefig(tmp, dpi=dpi, format=path.suffix[1:], metadata=meta, bbox_inches="tight")
    _pyplot().close(fig)
    return paths


def tracker_label(results: dict[str, Any]) -> str:
    """The tracker as a reader tells runs apart: its id and, when set, its options and delay mode
    (``srp-kalman:32x64 (alpha=0.5)``), so two configurations of one tracker never read the same."""
    delays = results_delays(results)
    return run_label(results, [f"delays={delays}"] if delays != "nearest" else [])


def _configuration_key(results: dict[str, Any]) -> str:
    """What makes two runs one line: tracker, options, weights and delays (not the task, so the
    per-cell files of one configuration join)."""
    from doabench.results.writer import results_configuration

    config = results_configuration(results)
    return json.dumps({k: config[k] for k in ("tracker", "options", "weights", "delays")}, sort_keys=True,
                      default=str)


def run_labels(runs: Sequence[dict[str, Any]], with_task: bool = False) -> list[str]:
    """One distinct legend label per run: :func:`tracker_label` (with the task when
    ``with_task``); runs whose labels still coincide (same options, other weights) get the
    weights' hash, then a running number."""
    labels = [tracker_label(r) + (f" on {(r.get('task') or {}).get('id')}" if with_task else "") for r in runs]
    for i, run in enumerate(runs):
        if labels.count(labels[i]) > 1:
            digest = (run.get("tracker") or {}).get("weights_hash")
            if digest:
                labels[i] += f" [{str(digest)[:8]}]"
    seen: dict[str, int] = {}
    for i, label in enumerate(list(labels)):
        seen[label] = seen.get(label, 0) + 1
        if seen[label] > 1:
            labels[i] = f"{label} #{seen[label]}"
    return labels


# -- line styles: colour, marker and dash together tell any number of lines apart -------------------
#: Line colours: matplotlib's tab10 (its default cycle), then six darker ones that differ from
#: those and from each other as much as tab10's own closest pair (red and brown, CIEDE2000 16);
#: no pale colour, so every line reads on white.
COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:gray",
           "tab:olive", "tab:cyan", "black", "navy", "maroon", "teal", "mediumvioletred", "#808000")
MARKERS = ("o", "s", "^", "D", "v", "<", ">", "p", "*", "h")
DASHES: tuple[Any, ...] = ("-", "--", ":", "-.")


@dataclass(frozen=True)
class LineStyle:
    """A line's colour, marker and dash pattern (a matplotlib linestyle)."""

    color: str
    marker: str
    linestyle: Any

    def kwargs(self) -> dict[str, Any]:
        return {"color": self.color, "marker": self.marker, "linestyle": self.linestyle}


def _dash(k: int, dashes: Sequence[Any]) -> Any:
    if k < len(dashes):
        return dashes[k]
    # Past the named patterns: dash followed by one dot more for each further pattern, all distinct.
    return (0, (6.0, 2.0) + (1.0, 2.0) * (k - len(dashes) + 2))


def line_styles(n: int, colours: Sequence[str] = COLOURS, markers: Sequence[str] = MARKERS,
                dashes: Sequence[Any] = DASHES) -> list[LineStyle]:
    """``n`` styles, no two alike in (colour, marker, dash), and within the first
    ``len(colours) * len(markers)`` no two alike in (colour, marker) either.

    Line ``i`` takes colour ``i mod C``, so up to C lines (16 with :data:`COLOURS`) never share a
    colour; each further round of C lines shifts the marker by one against the colour and takes
    the next dash pattern, so the 17th line of the default palette is a dashed blue square where
    the 1st is a solid blue circle. Past ``C * M`` lines the dash patterns continue (generated
    ones after the named ``dashes``)."""
    n_c, n_m = len(colours), len(markers)
    block = n_c * n_m
    out = []
    for i in range(n):
        r = i % block
        c, q = r % n_c, r // n_c
        # (c, q) -> (c, (c + q) mod M) is one-to-one within a block; the dash index grows by
        # len(dashes) from block to block, so the full triple never repeats.
        out.append(LineStyle(colours[c], markers[(c + q) % n_m],
                             _dash((i // block) * len(dashes) + q % len(dashes), dashes)))
    return out


def legend_outside(ax, max_width: float | None = None, min_panels_width: float = 0.0, **kwargs: Any):
    """A legend to the right of ``ax``, clear of its data. The figure widens by the legend's width,
    so that ``tight_layout`` does not squeeze the axes to make room for long labels; with
    ``max_width`` (inches) it widens no further than that, unless the panels would be left
    narrower than ``min_panels_width`` (then the panels keep that width and the figure is wider)."""
    legend = ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0, **kwargs)
    fig = ax.figure
    width_in = legend.get_window_extent(fig.canvas.get_renderer()).width / fig.dpi + 0.1
    width = fig.get_figwidth() + width_in
    if max_width is not None:
        width = max(min(width, max_width), min_panels_width + width_in)
    fig.set_figwidth(width)
    return legend


# -- Figs. 6 and 8: RMSAE versus T60 ------------------------------------------------------------------
def grid_curves(results: dict[str, Any], snr: float, metric: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(t60s, values, ci (n, 2))`` of a grid run's cells at one SNR, sorted by T60."""
    cells = [c for c in (results.get("cells") or {}).values() if math.isclose(float(c["snr"]), snr)]
    cells.sort(key=lambda c: float(c["t60"]))
    t60 = np.array([float(c["t60"]) for c in cells])
    values = np.array([float(c[metric]) for c in cells])
    ci = np.array([c.get(f"{metric}_ci95") or [np.nan, np.nan] for c in cells], float).reshape(-1, 2)
    return t60, values, ci


def cells_of(results: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """A run's cells: a grid run's ``cells``, or for a run of one grid cell (``sim-t60-0.3-snr-30``)
    that cell, from its summary."""
    if results.get("cells"):
        return dict(results["cells"])
    from doabench.results.identity import recorded_task_spec

    spec = recorded_task_spec(str(results["task"]["id"]))  # a results file's id resolves nothing else
    cell = spec.params.get("cell") if spec is not None else None
    if not cell or "t60" not in cell or "snr" not in cell:
        return {}
    s = results.get("summary") or {}
    return {results["task"]["id"]: {"t60": float(cell["t60"]), "snr": float(cell["snr"]),
                                    "rmsae_all": s.get("rmsae_all"), "rmsae_nonsilent": s.get("rmsae_nonsilent"),
                                    "rmsae_all_ci95": s.get("rmsae_all_ci95"),
                                    "rmsae_nonsilent_ci95": s.get("rmsae_nonsilent_ci95"),
                                    "n_episodes": (results.get("task") or {}).get("episodes_run")}}


def merge_cell_runs(runs: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Runs with cells, those of one tracker configuration merged into one (per-cell results files
    become one line; two configurations of a tracker stay two)."""
    merged: dict[str, dict[str, Any]] = {}
    for run in runs:
        cells = cells_of(run)
        if not cells:
            continue
        key = _configuration_key(run)
        if key not in merged:
            merged[key] = {**run, "cells": {}}
        merged[key]["cells"].update(cells)
    return list(merged.values())


def available_snrs(runs: Sequence[dict[str, Any]]) -> list[float]:
    return sorted({float(c["snr"]) for r in runs for c in (r.get("cells") or {}).values()})


def rmsae_vs_t60_figure(runs: Sequence[dict[str, Any]], snrs: Sequence[float] | None = None,
                        metric: str = "rmsae_nonsilent", title: str | None = None):
    """The figure of :func:`plot_rmsae_vs_t60`, not yet written."""
    if metric not in METRICS:
        raise InputError(f"--metric must be one of {', '.join(METRICS)}, not {metric!r}")
    grid_runs = merge_cell_runs(runs)
    if not grid_runs:
        raise InputError("none of the results files has per-cell results (run a grid task such as sim-grid, "
                         "or its cells such as sim-t60-0.3-snr-30)")
    known = available_snrs(grid_runs)
    snrs = list(snrs) if snrs else known
    missing = [s for s in snrs if not any(math.isclose(s, k) for k in known)]
    if missing:
        raise InputError(f"no cells with SNR {', '.join(f'{s:g}' for s in missing)} dB; "
                         f"the results have {', '.join(f'{s:g}' for s in known)}")
    plt = _pyplot()
    if len(snrs) <= 2:  # a row of panels, the legend right of them
        fig, row = plt.subplots(1, len(snrs), figsize=(4.6 * len(snrs), 3.8), sharey=True, squeeze=False)
        panels, legend_slot = list(row[0]), None
    else:
        fig, panels, legend_slot = panels_with_legend_slot(len(snrs))
    ordered = sorted(grid_runs, key=tracker_label)
    labels = run_labels(ordered)
    styles = line_styles(len(ordered))
    for ax, snr in zip(panels, snrs):
        for run, label, style in zip(ordered, labels, styles):
            t60, values, ci = grid_curves(run, snr, metric)
            ax.plot(t60, values, label=label, **style.kwargs())
            if np.all(np.isfinite(ci)):
                ax.fill_between(t60, ci[:, 0], ci[:, 1], color=style.color, alpha=0.15, linewidth=0)
        ax.set_title(f"SNR = {snr:g} dB")
        ax.set_xlabel("T60 [s]")
        ax.grid(True, alpha=0.3)
    for ax in panels:
        if ax.get_subplotspec().is_first_col():
            ax.set_ylabel(METRIC_LABELS[metric])
    panels[0].set_ylim(bottom=0)
    ncol = 1 if len(ordered) <= 16 else 2
    if legend_slot is None:
        legend_outside(panels[-1], max_width=PAGE_WIDTH_IN, min_panels_width=3.4 * len(panels), ncol=ncol)
    else:
        handles, texts = panels[0].get_legend_handles_labels()
        # a slot that spans a row (an even number of panels) is twice as wide: twice the columns
        legend_slot.legend(handles, texts, loc="center", fontsize="small", ncol=ncol if len(panels) % 2 else 2 * ncol)
    task = grid_runs[0]["task"]["id"]
    fig.suptitle(title or f"{task}: {METRIC_LABELS[metric].split(' [')[0]} versus T60 (bands: 95% bootstrap CI)")
    fig.tight_layout()
    return fig


def panels_with_legend_slot(n_panels: int, panel_size: tuple[float, float] = (5.0, 3.6)) -> tuple[Any, list[Any], Any]:
    """A figure of ``n_panels`` panels in two columns sharing their y axis, and an axes without
    axis lines for the legend in the next cell (with an even number of panels, a row of its own).
    Two columns keep the figure about 1100 pixels wide at :data:`FIGURE_DPI` however many panels
    there are. Returns ``(figure, panels, legend_slot)``."""
    plt = _pyplot()
    cols = 2
    rows = math.ceil((n_panels + 1) / cols)
    fig = plt.figure(figsize=(cols * panel_size[0], rows * panel_size[1]))
    grid = fig.add_gridspec(rows, cols)
    panels: list[Any] = []
    for i in range(n_panels):
        ax = fig.add_subplot(grid[i // cols, i % cols], sharey=panels[0] if panels else None)
        if i % cols:
            ax.tick_params(labelleft=False)  # the left panel of the row carries the values
        panels.append(ax)
    legend_slot = fig.add_subplot(grid[n_panels // cols, n_panels % cols] if n_panels % cols
                                  else grid[n_panels // cols, :])
    legend_slot.axis("off")
    return fig, panels, legend_slot


def plot_rmsae_vs_t60(runs: Sequence[dict[str, Any]], out: str | Path, snrs: Sequence[float] | None = None,
                      metric: str = "rmsae_nonsilent", title: str | None = None) -> list[Path]:
    """One panel per SNR, one line per tracker configuration with its 95% bootstrap band, each
    line its own colour, marker and dash (:func:`line_styles`). One or two panels stand in a row
    with the legend right of them; three or more make a grid of two columns with the legend in
    a cell of its own (:func:`panels_with_legend_slot`)."""
    return save_figure(rmsae_vs_t60_figure(runs, snrs, metric, title), out)


# -- RMSAE by angular speed of the truth --------------------------------------------------------------
SPEED_LABEL = "RMSAE, voice-active frames [deg]"


def speed_bands_of(results: dict[str, Any], source: str = "a results file") -> dict[str, dict[str, Any]]:
    """``summary.speed_bands`` of a results file; InputError naming ``source`` when it has none."""
    bands = (results.get("summary") or {}).get("speed_bands")
    if not isinstance(bands, dict) or not bands:
        raise InputError(f"{source} has no summary.speed_bands (RMSAE by angular speed): it was written "
                         "before doabench recorded them; run the task again")
    return bands


def rmsae_vs_speed_figure(runs: Sequence[dict[str, Any]], title: str | None = None,
                          sources: Sequence[str] | None = None):
    """The figure of :func:`plot_rmsae_vs_speed`, not yet written."""
    if not runs:
        raise InputError("no results files to plot")
    sources = list(sources) if sources is not None else [f"results file {i + 1}" for i in range(len(runs))]
    bands = [speed_bands_of(run, source) for run, source in zip(runs, sources)]
    # The bands as the files name them, slowest first (the runner writes doabench.metrics.SPEED_BANDS
    # in that order); read from the files so a file keeps plotting if the bands ever change.
    names = list(dict.fromkeys(name for b in bands for name in b))
    tasks = [str((r.get("task") or {}).get("id")) for r in runs]
    labels = run_labels(runs, with_task=len(set(tasks)) > 1)
    order = sorted(range(len(runs)), key=lambda i: labels[i])
    styles = line_styles(len(runs))
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 3.8))
    x = np.arange(len(names))

    def value(band: dict[str, Any] | None) -> float:
        v = (band or {}).get("rmsae")
        return math.nan if v is None or not (band or {}).get("n_frames") else float(v)

    for style, i in zip(styles, order):
        ax.plot(x, [value(bands[i].get(name)) for name in names], label=labels[i], **style.kwargs())
    counts = [{int((b.get(name) or {}).get("n_frames") or 0) for b in bands} for name in names]
    ticks = names
    if all(len(c) == 1 for c in counts):  # one task: every line has the same frames per band
        ticks = [f"{name}\n{next(iter(c))} frames" for name, c in zip(names, counts)]
    ax.set_xticks(x)
    ax.set_xticklabels(ticks)
    ax.set_xlim(-0.4, len(names) - 0.6)
    ax.set_xlabel("angular speed of the truth, seen from the array [deg/s]")
    ax.set_ylabel(SPEED_LABEL)
    ax.set_ylim(bottom=0)
    ax.grid(True, alpha=0.3)
    legend_outside(ax, ncol=1 if len(runs) <= 16 else 2)
    task_text = ", ".join(dict.fromkeys(tasks))
    fig.suptitle(title or f"{task_text}: RMSAE of voice-active frames by angular speed of the truth",
                 fontsize="medium")
    fig.tight_layout()
    return fig


def plot_rmsae_vs_speed(runs: Sequence[dict[str, Any]], out: str | Path, title: str | None = None,
                        sources: Sequence[str] | None = None) -> list[Path]:
    """RMSAE of the voice-active frames per angular-speed band of the truth (``<5``, ``5-15``,
    ``15-30``, ``>30`` deg/s; ``summary.speed_bands``), one line per run in the distinct styles of
    :func:`line_styles`. ``sources`` name the runs in errors (the files they came from)."""
    return save_figure(rmsae_vs_speed_figure(runs, title, sources), out)


# -- Fig. 7: one episode ------------------------------------------------------------------------------
class EpisodeFrames(TypedDict):
    """One episode's stored frames (:func:`episode_frames`)."""

    times: np.ndarray
    estimates: np.ndarray
    truth: np.ndarray
    row: dict[str, Any]
    vad: np.ndarray | None  # results files written before the VAD was kept per frame have none


def episode_frames(results: dict[str, Any], episode: int) -> EpisodeFrames:
    """Stored per-frame times, estimates and truth of the ``episode``-th row of a results file."""
    rows = results.get("episodes") or []
    frames = results.get("frames")
    if not frames:
        raise InputError("this results file has no per-frame estimates (it was run with --no-frames)")
    positions = [i for i, row in enumerate(rows) if int(row["episode"]) == episode]
    if not positions:
        have = ", ".join(str(r["episode"]) for r in rows[:10])
        raise InputError(f"episode {episode} is not in the results file (it has episodes {have}"
                         f"{', ...' if len(rows) > 10 else ''})")
    f = frames[positions[0]]
    return {"times": np.asarray(f["times"], float), "estimates": np.asarray(f["estimates"], float),
            "truth": np.asarray(f["truth"], float), "row": rows[positions[0]],
            "vad": None if f.get("vad") is None else np.asarray(f["vad"], bool)}


def render_episode(task: str, episode: int, resolution: str | tuple[int, int], **source_options: Any):
    """Re-render an episode through the task's environment: ``(episode, srp maps (T, θ, φ), truth)``."""
    from doabench.envs.env import DoaEnv

    env = DoaEnv(task, features=("srp",), resolution=resolution, **source_options)
    if not 0 <= episode < env.n_episodes:
        raise InputError(f"task {task!r} has {env.n_episodes} episodes; episode {episode} does not exist")
    ep, feats, truth = env.load_episode(episode)
    return ep, feats["srp"], truth, env.array


def _degrees(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from doabench.geometry import unit_to_angles

    el, az = unit_to_angles(np.asarray(u, float))
    return np.degrees(el), np.degrees(az)


def _break_wraps(t: np.ndarray, az: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Insert NaNs where azimuth wraps around ±180 so the line does not cross the whole plot."""
    if len(az) < 2:
        return t, az
    jumps = np.where(np.abs(np.diff(az)) > 180)[0] + 1
    return np.insert(t.astype(float), jumps, np.nan), np.insert(az.astype(float), jumps, np.nan)


def _shade_silence(ax, times: np.ndarray, vad: np.ndarray) -> None:
    if len(times) < 2:
        return
    step = float(np.median(np.diff(times)))
    silent = ~np.asarray(vad, bool)
    start = None
    for i, s in enumerate(list(silent) + [False]):
        if s and start is None:
            start = i
        elif not s and start is not None:
            ax.axvspan(times[start] - step / 2, times[i - 1] + step / 2, color="0.85", linewidth=0, zorder=0)
            start = None


#: the truth's colour in the episode plot; estimates take the other colours
TRUTH_COLOUR = "tab:red"


def episode_figure(results: dict[str, Any], episode: int, maxima: np.ndarray | None = None,
                   vad: np.ndarray | None = None, maxima_label: str = "SRP-PHAT maximum",
                   title: str | None = None, others: Sequence[dict[str, Any]] = ()):
    """The figure of :func:`plot_episode`, not yet written."""
    from matplotlib.patches import Patch

    runs = [results, *others]
    frames = [episode_frames(r, episode) for r in runs]
    f = frames[0]
    t = f["times"]
    el_t, az_t = _degrees(f["truth"])
    labels = run_labels(runs)
    # Estimates: every colour but the truth's, dashed first (the truth is the one solid red line);
    # markers every few frames so lines of the same colour family still read apart.
    styles = line_styles(len(runs), colours=[c for c in COLOURS if c != TRUTH_COLOUR], dashes=("--", "-.", ":", "-"))
    every = max(1, len(t) // 12)
    plt = _pyplot()
    fig, axes = plt.subplots(2, 1, figsize=(7.5, 5.0), sharex=True)
    for ax, truth, index, name, lim in ((axes[0], el_t, 0, "elevation [deg]", (0, 180)),
                                        (axes[1], az_t, 1, "azimuth [deg]", (-180, 180))):
        if vad is not None:
            _shade_silence(ax, t, vad)
        if maxima is not None:
            m = _degrees(maxima)[index]
            ax.plot(t, m, "x", color="0.35", markersize=4, label=maxima_label)
        ax.plot(*(_break_wraps(t, truth) if index else (t, truth)), "-", color=TRUTH_COLOUR, linewidth=1.8,
                label="truth")
        for fr, label, style in zip(frames, labels, styles):
            e = _degrees(fr["estimates"])[index]
            ax.plot(*(_break_wraps(t, e) if index else (t, e)), linewidth=1.4, markersize=4, markevery=every,
                    label=f"{label}: RMSAE {fr['row']['rmsae_all']:.1f}° all frames", **style.kwargs())
        ax.set_ylabel(name)
        ax.set_ylim(*lim)
        ax.set_yticks(np.arange(lim[0], lim[1] + 1, 45))
        ax.grid(True, alpha=0.3)
    axes[1].set_xlabel("time [s]")
    handles, _ = axes[0].get_legend_handles_labels()
    if vad is not None and not np.all(vad):
        handles.append(Patch(color="0.85", label="silent frames"))
    # right of the elevation panel, never over either panel's lines
    legend_outside(axes[0], max_width=PAGE_WIDTH_IN, min_panels_width=5.5, handles=handles)
    row = f["row"]
    scene = ", ".join(x for x in (
        f"T60 {row['t60']:.2g} s" if row.get("t60") is not None else "",
        f"SNR {row['snr']:.3g} dB" if row.get("snr") is not None else "") if x)
    fig.suptitle(title or f"{row.get('task') or results['task']['id']} episode {episode}"
                 + (f" ({scene})" if scene else "") + ("; grey = silent" if vad is not None else ""),
                 fontsize="medium")
    fig.tight_layout()
    return fig


def plot_episode(results: dict[str, Any], episode: int, out: str | Path, maxima: np.ndarray | None = None,
                 vad: np.ndarray | None = None, maxima_label: str = "SRP-PHAT maximum",
                 title: str | None = None, others: Sequence[dict[str, Any]] = ()) -> list[Path]:
    """Elevation and azimuth over time: truth (solid red), each run's estimate (its own colour,
    dash and marker, labelled with its options and RMSAE), map maxima (crosses), grey silent
    frames; the legend right of the panels. ``maxima (T, 3)`` come from re-rendering the episode,
    ``vad (T,)`` from re-rendering or the results file. ``others``: more runs of the same task."""
    return save_figure(episode_figure(results, episode, maxima, vad, maxima_label, title, others), out)


# -- Figs. 1 and 2: SRP-PHAT maps -------------------------------------------------------------------
def srp_maps(task: str, episode: int, frame: int, resolutions: Sequence[tuple[int, int]], delays: str = "nearest",
             **source_options: Any) -> dict[str, Any]:
    """Render one episode once and compute its SRP-PHAT map at ``frame`` for each resolution.

    Returns ``maps`` ({resolution: map}), ``direction`` (true DOA (3,)), ``active`` (frame is
    voice-active), ``episode`` and ``array``."""
    from doabench.envs.env import DoaEnv
    from doabench.features.spec import ObservationSpec

    env = DoaEnv(task, features=("srp",), resolution=resolutions[0], delays=delays, **source_options)
    if not 0 <= episode < env.n_episodes:
        raise InputError(f"task {task!r} has {env.n_episodes} episodes; episode {episode} does not exist")
    ep = env.source.episode(episode)
    truth = ep.frame_truth(env.frame_spec)
    n = len(truth["directions"])
    if not 0 <= frame < n:
        raise InputError(f"episode {episode} of {task!r} has {n} frames; frame {frame} does not exist")
    array = ep.array or env.array
    maps = {}
    for res in resolutions:
        plan = ObservationSpec.of(("srp",), res, env.frame_spec, delays).plan(array)
        maps[tuple(res)] = plan.observations(ep.audio, ep.sample_vad)["srp"][frame]
    return {"maps": maps, "direction": truth["directions"][frame], "active": bool(truth["vad"][frame]),
            "episode": ep, "array": array}


def plot_maps(maps: dict[tuple[int, int], np.ndarray], true_direction: np.ndarray, out: str | Path,
              planar: bool = False, title: str = "") -> list[Path]:
    """SRP-PHAT maps side by side; red dot: true DOA, black dot: the map's maximum (as in the
    paper); the legend below the maps."""
    return save_figure(maps_figure(maps, true_direction, planar, title), out)


def maps_figure(maps: dict[tuple[int, int], np.ndarray], true_direction: np.ndarray, planar: bool = False,
                title: str = ""):
    """The figure of :func:`plot_maps`, not yet written."""
    from doabench.geometry import grid_angles

    plt = _pyplot()
    n = len(maps)
    cols = min(n, 2)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5.2 * cols, 3.0 * rows), squeeze=False)
    el_true, az_true = (float(v) for v in _degrees(true_direction))
    for ax, ((n_theta, n_phi), m) in zip(axes.flat, maps.items()):
        el, az = grid_angles(n_theta, n_phi, planar)
        el, az = np.degrees(el), np.degrees(az)
        d_el = el[1] - el[0]
        d_az = 360.0 / n_phi
        image = ax.imshow(m, origin="upper", aspect="auto", cmap="viridis", interpolation="nearest",
                          extent=(az[0] - d_az / 2, az[-1] + d_az / 2, el[-1] + d_el / 2, el[0] - d_el / 2))
        fig.colorbar(image, ax=ax, fraction=0.05, pad=0.02, label="normalised SRP (max 1)")
        i, j = np.unravel_index(int(np.argmax(m)), m.shape)
        ax.plot(az[j], el[i], "o", color="black", markersize=7, markeredgecolor="white", label="map maximum")
        ax.plot(az_true, el_true, "o", color="red", markersize=7, markeredgecolor="white", label="true DOA")
        ax.set_title(f"{n_theta}x{n_phi}")
        ax.set_xlabel("azimuth [deg]")
        ax.set_ylabel("elevation [deg]")
        ax.set_xticks(np.arange(-180, 181, 90))
        ax.set_yticks(np.arange(0, 181 if not planar else 91, 45))
        ax.set_xlim(az[0] - d_az / 2, az[-1] + d_az / 2)
    for ax in list(axes.flat)[n:]:
        ax.set_visible(False)
    if title:
        fig.suptitle(title, fontsize="medium")
    # Below the maps (a legend inside would hide map cells): room for one row at the bottom.
    fig.tight_layout(rect=(0.0, 0.35 / fig.get_figheight(), 1.0, 1.0))
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize="x-small", loc="lower center", ncol=len(handles), bbox_to_anchor=(0.5, 0.0))
    return fig


# -- training curves -----------------------------------------------------------------------------
def read_training_log(path: str | Path) -> dict[str, np.ndarray]:
    """Columns of a ``doabench train`` ``log.csv`` as float arrays (empty cells are NaN)."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise InputError(f"training log {path} does not exist") from None
    rows = list(csv.DictReader(text.splitlines()))
    if not rows or "epoch" not in rows[0]:
        raise InputError(f"{path} is not a training log (needs a header with an 'epoch' column and rows)")

    def value(x: str | None) -> float:
        try:
            return float(x) if x not in (None, "") else math.nan
        except ValueError:
            return math.nan

    return {k: np.array([value(r.get(k)) for r in rows]) for k in rows[0]}


def plot_training(logs: dict[str, dict[str, np.ndarray]], out: str | Path) -> list[Path]:
    """Loss (log scale) and validation RMSAE per epoch, one colour and marker per run (solid:
    train / all frames, dashed: validation / non-silent); legends below the panels."""
    return save_figure(training_figure(logs), out)


def training_figure(logs: dict[str, dict[str, np.ndarray]]):
    """The figure of :func:`plot_training`, not yet written."""
    plt = _pyplot()
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 3.8))
    # The dash says which curve of a run it is, so runs differ by colour and marker only:
    # line_styles' (colour, marker) pairs are distinct for the first 100 runs.
    runs = sorted(logs.items())
    for (name, log), run_style in zip(runs, line_styles(len(runs))):
        epochs = log["epoch"]
        look = {"color": run_style.color, "marker": run_style.marker, "markersize": 4}
        prefix = f"{name}: " if len(logs) > 1 else ""
        for key, style, label in (("train_loss", "-", "train"), ("val_loss", "--", "validation")):
            if key in log and np.any(np.isfinite(log[key])):
                ax1.plot(epochs, log[key], linestyle=style, label=prefix + label, **look)
        for key, style, label in (("val_rmsae_all", "-", "all frames"), ("val_rmsae_nonsilent", "--", "non-silent")):
            if key in log and np.any(np.isfinite(log[key])):
                ax2.plot(epochs, log[key], linestyle=style, label=prefix + label, **look)
    ax1.set_xlabel("epoch")
    ax1.set_ylabel("loss")
    if any(np.nanmin(log.get(k, [np.nan])) > 0 for log in logs.values() for k in ("train_loss",)
           if k in log and np.any(np.isfinite(log[k]))):
        ax1.set_yscale("log")
    ax2.set_xlabel("epoch")
    ax2.set_ylabel("validation RMSAE [deg]")
    for ax in (ax1, ax2):
        ax.grid(True, alpha=0.3)
        if ax.get_legend_handles_labels()[0]:  # below the panel, clear of the curves
            ax.legend(fontsize="small", loc="upper center", bbox_to_anchor=(0.5, -0.18), ncol=2)
    fig.suptitle("training: " + ", ".join(sorted(logs)), fontsize="medium")
    fig.tight_layout()
    return fig


# -- conventions figure (docs/concepts.md) ----------------------------------------------------------
def plot_conventions(array, resolution: tuple[int, int], out: str | Path) -> list[Path]:
    """The array frame and the SRP grid: microphones seen from above and from the side (axes of
    the array frame), and the grid's points on the (azimuth, elevation) plane with the named
    directions (+x, +y, up, down) marked."""
    return save_figure(conventions_figure(array, resolution), out)


def conventions_figure(array, resolution: tuple[int, int]):
    """The figure of :func:`plot_conventions`, not yet written."""
    from doabench.geometry import grid_angles

    plt = _pyplot()
    # 11.4 inches: 1254 pixels at FIGURE_DPI, readable on a 1280-pixel page
    fig, axes = plt.subplots(1, 3, figsize=(11.4, 3.7), gridspec_kw={"width_ratios": [1, 1, 2.1]})
    pos = np.asarray(array.positions) * 100.0
    for ax, (i, j, a, b) in zip(axes[:2], ((0, 1, "x", "y"), (0, 2, "x", "z"))):
        ax.scatter(pos[:, i], pos[:, j], s=28, color="C0", zorder=3)
        for k, p in enumerate(pos):
            ax.annotate(str(k + 1), (p[i], p[j]), fontsize=7, xytext=(3, 3), textcoords="offset points")
        ax.axhline(0, color="0.6", lw=0.8)
        ax.axvline(0, color="0.6", lw=0.8)
        span = float(np.abs(pos).max()) * 1.35
        ax.annotate("", xy=(span * 0.9, 0), xytext=(0, 0), arrowprops={"arrowstyle": "->", "color": "C3"})
        ax.annotate("", xy=(0, span * 0.9), xytext=(0, 0), arrowprops={"arrowstyle": "->", "color": "C3"})
        ax.text(span * 0.92, 0, f"+{a}", color="C3", va="center")
        ax.text(0, span * 0.93, f"+{b}", color="C3", ha="center")
        ax.set_xlim(-span, span)
        ax.set_ylim(-span, span)
        ax.set_aspect("equal")
        ax.set_xlabel(f"{a} [cm]")
        ax.set_ylabel(f"{b} [cm]")
        ax.set_title(f"array '{array.name}' seen {'from above' if j == 1 else 'from the side'}", fontsize="medium")
    n_theta, n_phi = resolution
    el, az = np.degrees(grid_angles(n_theta, n_phi, array.planar)[0]), np.degrees(grid_angles(n_theta, n_phi,
                                                                                                array.planar)[1])
    ax = axes[2]
    A, E = np.meshgrid(az, el)
    ax.scatter(A.ravel(), E.ravel(), s=12, color="C0", label=f"{n_theta}x{n_phi} grid points")
    named_directions = {"+x (az 0°, el 90°)": (0, 90), "+y (az 90°)": (90, 90), "−x (az −180°)": (-180, 90),
                        "−y (az −90°)": (-90, 90), "up, +z (el 0°)": (0, 0), "down, −z (el 180°)": (0, 180)}
    for name, (az_deg, el_deg) in named_directions.items():
        ax.plot(az_deg, el_deg, "o", ms=9, mfc="none", mec="C3")
        ax.annotate(name, (az_deg, el_deg), fontsize=7, color="C3", xytext=(5, 4), textcoords="offset points")
    ax.set_xlim(-190, 190)
    ax.set_ylim(190, -10)
    ax.set_xticks(np.arange(-180, 181, 45))
    ax.set_yticks(np.arange(0, 181, 45))
    ax.set_xlabel("azimuth φ = atan2(y, x) [deg]")
    ax.set_ylabel("elevation θ from +z [deg]")
    ax.set_title(f"SRP grid: θ_i = 180°·i/{n_theta - 1}, φ_j = −180° + 360°·j/{n_phi}", fontsize="medium")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="x-small", loc="upper center", bbox_to_anchor=(0.5, -0.16))  # below: clear of the grid
    fig.tight_layout()
    return fig
