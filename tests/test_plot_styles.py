"""Figures a reader can tell apart: 16 distinct colours, then every line its own colour, marker
and dash however many trackers there are, labels that carry the tracker's options, legends clear
of the data, panels in two columns that fit a 1280-pixel page, the RMSAE-by-angular-speed plot,
and help texts that say what the plots do."""
from __future__ import annotations

from doabench.results.schema import load_results

import copy
import json
from pathlib import Path

import numpy as np
import pytest

from doabench.cli.main import main
from doabench.reporting import plots
from doabench.results.upgrade import upgrade_results
from test_leaderboard import _results


def _write(path: Path, results: dict) -> str:
    path.write_text(json.dumps(results))
    return str(path)


def _with_options(results: dict, **options) -> dict:
    out = copy.deepcopy(results)
    out["tracker"]["options"] = dict(options)
    return out


def _with_speed_bands(results: dict, values: dict[str, float | None]) -> dict:
    out = copy.deepcopy(results)
    out["summary"]["speed_bands"] = {band: {"rmsae": v, "n_frames": 0 if v is None else 40}
                                     for band, v in values.items()}
    return out


def _legends(fig) -> list:
    return [*fig.legends, *(ax.get_legend() for ax in fig.axes if ax.get_legend() is not None)]


def _assert_legends_clear_of_axes(fig) -> None:
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    legends = _legends(fig)
    assert legends, "the figure has no legend"
    for legend in legends:
        box = legend.get_window_extent(renderer)
        for ax in fig.axes:
            if ax.get_visible() and ax.axison:  # an axes without axis lines is a legend's own cell
                assert not box.overlaps(ax.get_window_extent(renderer)), (
                    f"legend over the panel {ax.get_title() or ax.get_ylabel()!r}")


@pytest.mark.parametrize("n", [1, 10, 11, 13, 30, 100, 101, 250])
def test_line_styles_are_unique_for_any_number_of_trackers(n: int) -> None:
    styles = plots.line_styles(n)
    triples = [(s.color, s.marker, str(s.linestyle)) for s in styles]
    assert len(set(triples)) == n
    first = triples[:len(plots.COLOURS) * len(plots.MARKERS)]
    assert len({(c, m) for c, m, _ in first}) == len(first)  # colour and marker alone tell them apart too
    up_to_16 = triples[:16]
    assert len({c for c, _, _ in up_to_16}) == len(up_to_16)  # up to 16 lines never share a colour


def test_the_palette_has_16_distinct_colours_and_none_is_pale() -> None:
    import matplotlib.colors as mcolors

    hexes = [mcolors.to_hex(c) for c in plots.COLOURS]
    assert len(plots.COLOURS) >= 16 and len(set(hexes)) == len(hexes)
    assert hexes[:10] == [mcolors.to_hex(f"C{i}") for i in range(10)]  # matplotlib's default cycle first
    for colour in plots.COLOURS:
        r, g, b = (c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4 for c in mcolors.to_rgb(colour))
        assert 0.2126 * r + 0.7152 * g + 0.0722 * b < 0.5, f"{colour} is too pale to read on white"
    assert plots.TRUTH_COLOUR in plots.COLOURS  # the episode plot keeps it for the truth alone


def test_thirty_trackers_draw_thirty_distinct_lines_in_rmsae_vs_t60() -> None:
    runs = [_results(f"srp-max:{4 * (k + 1)}x{8 * (k + 1)}", 10.0 + k) for k in range(30)]
    fig = plots.rmsae_vs_t60_figure(runs, snrs=[30.0])
    import matplotlib.colors as mcolors
    import matplotlib.pyplot as plt

    ax = fig.axes[0]
    lines = [ln for ln in ax.get_lines() if not ln.get_label().startswith("_")]
    assert len(lines) == 30
    # Colour and marker alone already differ for every pair (the 1st and the 11th line used to be
    # two blue circles), the first 16 differ in colour alone, and the dash changes with every
    # round of sixteen.
    assert len({(mcolors.to_hex(ln.get_color()), ln.get_marker()) for ln in lines}) == 30
    assert len({mcolors.to_hex(ln.get_color()) for ln in lines[:16]}) == 16
    assert [ln.get_linestyle() for ln in lines] == ["-"] * 16 + ["--"] * 14
    assert len({ln.get_label() for ln in lines}) == 30
    assert all(ln.get_label() in [t.get_text() for t in ax.get_legend().get_texts()] for ln in lines)
    plt.close(fig)


def test_labels_carry_tracker_options() -> None:
    base = _results("srp-kalman:32x64", 12.0)
    a, b = _with_options(base, alpha=0.5), _with_options(base, alpha=0.9)
    assert plots.tracker_label(a) == "srp-kalman:32x64 (alpha=0.5)"
    assert plots.tracker_label(a) != plots.tracker_label(b)
    assert plots.tracker_label(base) == "srp-kalman:32x64"
    weights = _with_options(base, weights="/somewhere/runs/c16/model.safetensors")
    assert plots.tracker_label(weights) == "srp-kalman:32x64 (weights=model.safetensors)"
    exact = copy.deepcopy(base)
    exact["features"]["delays"] = "exact"
    exact = upgrade_results(exact)  # a doabench.results/1 file, read as the current schema
    assert plots.tracker_label(exact) == "srp-kalman:32x64 (delays=exact)"
    # Same label, other weights: the hash tells them apart; otherwise a running number.
    w1, w2 = copy.deepcopy(weights), copy.deepcopy(weights)
    w1["tracker"]["weights_hash"], w2["tracker"]["weights_hash"] = "ab" * 32, "cd" * 32
    labels = plots.run_labels([w1, w2])
    assert len(set(labels)) == 2 and "abababab" in labels[0]
    assert plots.run_labels([base, base]) == ["srp-kalman:32x64", "srp-kalman:32x64 #2"]


def test_two_alpha_runs_read_differently_in_the_episode_plot() -> None:
    base = _results("srp-kalman:32x64", 12.0)
    a, b = _with_options(base, alpha=0.5), _with_options(base, alpha=0.9)
    fig = plots.episode_figure(a, 1, others=[b], vad=np.array([1, 1, 0, 1, 1], bool))
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert any("alpha=0.5" in t for t in labels) and any("alpha=0.9" in t for t in labels)
    estimates = [ln for ln in fig.axes[0].get_lines() if "alpha" in ln.get_label()]
    assert len({(ln.get_color(), ln.get_marker(), ln.get_linestyle()) for ln in estimates}) == 2
    truth = [ln for ln in fig.axes[0].get_lines() if ln.get_label() == "truth"]
    assert all(ln.get_color() != truth[0].get_color() for ln in estimates)


def test_rmsae_vs_t60_keeps_two_configurations_of_a_tracker_apart() -> None:
    base = _results("srp-kalman:32x64", 12.0)
    merged = plots.merge_cell_runs([_with_options(base, alpha=0.5), _with_options(base, alpha=0.9)])
    assert len(merged) == 2  # they used to merge into one line under one label


def test_legends_are_outside_the_data() -> None:
    import matplotlib.pyplot as plt

    runs = [_results(f"srp-max:{4 * (k + 1)}x{8 * (k + 1)}", 10.0 + k) for k in range(12)]
    speed = {"<5": 8.0, "5-15": 10.0, "15-30": 14.0, ">30": 20.0}
    log = {"epoch": np.arange(1, 4.0), "train_loss": np.array([1.0, 0.5, 0.3]), "val_loss": np.array([1.1, 0.6, 0.4]),
           "val_rmsae_all": np.array([30.0, 20.0, 15.0]), "val_rmsae_nonsilent": np.array([25.0, 18.0, 12.0])}
    from doabench.arrays import get_array

    figures = {
        "rmsae-vs-t60": plots.rmsae_vs_t60_figure(runs),
        "episode": plots.episode_figure(runs[0], 1, others=runs[1:3], vad=np.array([1, 1, 0, 1, 1], bool),
                                        maxima=np.tile([[0.0, 1.0, 0.0]], (5, 1))),
        "rmsae-vs-speed": plots.rmsae_vs_speed_figure([_with_speed_bands(r, speed) for r in runs[:5]]),
        "maps": plots.maps_figure({(8, 16): np.random.default_rng(0).random((8, 16)),
                                   (4, 8): np.random.default_rng(1).random((4, 8))}, np.array([0.0, 1.0, 0.0])),
        "training": plots.training_figure({"a": log, "b": log}),
        "conventions": plots.conventions_figure(get_array("nao"), (8, 16)),
    }
    for name, fig in figures.items():
        try:
            _assert_legends_clear_of_axes(fig)
        except AssertionError as exc:
            raise AssertionError(f"plot {name}: {exc}") from None
        finally:
            plt.close(fig)


def test_rmsae_vs_speed_draws_one_line_per_tracker(tmp_path: Path, capsys) -> None:
    files = []
    for k, tracker in enumerate(["srp-max:8x16", "srp-kalman:32x64", "srp-max:16x32"]):
        bands = {"<5": 5.0 + k, "5-15": 8.0 + k, "15-30": 12.0 + k, ">30": None if k == 0 else 25.0 + k}
        files.append(_write(tmp_path / f"{k}.json", _with_speed_bands(_results(tracker, 10.0), bands)))
    runs = [load_results(f) for f in files]
    fig = plots.rmsae_vs_speed_figure(runs)
    ax = fig.axes[0]
    lines = ax.get_lines()
    assert len(lines) == 3
    assert [t.get_text().split("\n")[0] for t in ax.get_xticklabels()] == ["<5", "5-15", "15-30", ">30"]
    by_label = {ln.get_label(): ln for ln in lines}
    y = by_label["srp-max:8x16"].get_ydata()
    assert list(y[:3]) == [5.0, 8.0, 12.0] and np.isnan(y[3])  # a band without frames is a gap, not a zero
    assert list(by_label["srp-kalman:32x64"].get_ydata()) == [6.0, 9.0, 13.0, 26.0]
    assert len({(ln.get_color(), ln.get_marker(), ln.get_linestyle()) for ln in lines}) == 3
    import matplotlib.pyplot as plt

    plt.close(fig)
    out = tmp_path / "speed"
    assert main(["plot", "rmsae-vs-speed", *files, "--out", str(out)]) == 0
    assert (tmp_path / "speed.png").stat().st_size > 1000 and (tmp_path / "speed.pdf").is_file()


def test_rmsae_vs_speed_names_a_file_without_speed_bands(tmp_path: Path, capsys) -> None:
    good = _write(tmp_path / "good.json", _with_speed_bands(_results("srp-max", 5.0), {"<5": 4.0, "5-15": 5.0,
                                                                                       "15-30": 6.0, ">30": 7.0}))
    old = _write(tmp_path / "old.json", _results("srp-kalman:32x64", 5.0))
    capsys.readouterr()
    assert main(["plot", "rmsae-vs-speed", good, old, "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip()
    assert old in err and "speed_bands" in err and "\n" not in err and "Traceback" not in err
    assert not (tmp_path / "x.png").exists()


def test_no_render_help_matches_what_is_drawn(tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit):
        main(["plot", "episode", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "no SRP maxima; silent frames are still shaded" in help_text
    # ... and with --no-render the silent frame of the stored VAD is shaded.
    f = _write(tmp_path / "a.json", _results("srp-max:8x16", 30.0))
    captured = {}
    original = plots.save_figure

    def spy(fig, out, *a, **k):
        captured["patches"] = [p for p in fig.axes[0].patches]
        captured["legend"] = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
        return original(fig, out, *a, **k)

    plots.save_figure = spy
    try:
        assert main(["plot", "episode", f, "--episode", "1", "--no-render", "--out", str(tmp_path / "ep")]) == 0
    finally:
        plots.save_figure = original
    assert len(captured["patches"]) == 1 and "silent frames" in captured["legend"]


def test_leaderboards_comparisons_and_legends_name_a_configuration_alike():
    from doabench.results.labels import run_label
    from doabench.results.ranking import RunFile

    results = {"tracker": {"id": "srp-kalman:32x64", "options": {"weights": "/tmp/x/model.safetensors", "alpha": 0.5}},
               "task": {"id": "sim-grid"}}
    expected = "srp-kalman:32x64 (alpha=0.5, weights=model.safetensors)"
    assert plots.tracker_label(results) == run_label(results) == expected
    assert RunFile("a.json", "0" * 64, results).tracker_id == expected


def test_a_long_legend_label_widens_the_figure_not_squeezes_the_axes() -> None:
    import matplotlib.pyplot as plt

    bands = {"<5": 5.0, "5-15": 8.0, "15-30": 12.0, ">30": 20.0}
    short = _with_speed_bands(_results("srp-max:8x16", 10.0), bands)
    long = copy.deepcopy(short)
    long["tracker"]["options"] = {"weights": "a-model-file-with-a-rather-long-descriptive-name.safetensors"}
    widths = []
    for runs in ([short], [short, long]):
        fig = plots.rmsae_vs_speed_figure(runs)
        fig.canvas.draw()
        widths.append((fig.axes[0].get_window_extent().width / fig.dpi, fig.get_figwidth()))
        _assert_legends_clear_of_axes(fig)
        plt.close(fig)
    (axes_short, fig_short), (axes_long, fig_long) = widths
    assert axes_long == pytest.approx(axes_short, rel=0.05)
    assert fig_long > fig_short + 1.0


def _grid_results(tracker: str, base: float) -> dict:
    """A sim-grid-like run with cells at four SNRs."""
    out = _results(tracker, base)
    out["cells"] = {f"t{t60}-s{snr}": {"t60": t60, "snr": snr, "rmsae_all": base + t60 + snr / 10,
                                       "rmsae_nonsilent": base + t60, "n_episodes": 2}
                    for t60 in (0.3, 0.9) for snr in (5.0, 15.0, 20.0, 30.0)}
    return out


@pytest.mark.parametrize("n_snrs", [1, 2, 3, 4])
def test_rmsae_vs_t60_fits_a_1280_pixel_page(n_snrs: int, tmp_path: Path) -> None:
    """Three or more SNR panels make a grid of two columns with the legend in a cell of its own;
    one or two stand in a row with the legend right of them. The PNG stays about 1280 pixels wide
    with 13 labelled lines (the docs' Fig. 8)."""
    from PIL import Image

    runs = [_grid_results(f"srp-max:{4 * (k + 1)}x{8 * (k + 1)}", 10.0 + k) for k in range(13)]
    for run in runs:
        run["tracker"]["options"] = {"weights": "a-model-of-typical-name.safetensors"}
    snrs = [5.0, 15.0, 20.0, 30.0][:n_snrs]
    fig = plots.rmsae_vs_t60_figure(runs, snrs=snrs)
    panels = [ax for ax in fig.axes if ax.axison]
    assert len(panels) == n_snrs
    if n_snrs >= 3:
        columns = {round(ax.get_position().x0, 3) for ax in panels}
        assert len(columns) == 2
        [slot] = [ax for ax in fig.axes if not ax.axison]
        assert slot.get_legend() is not None and len(slot.get_legend().get_texts()) == 13
    _assert_legends_clear_of_axes(fig)
    paths = plots.save_figure(fig, tmp_path / "fig")
    width, _ = Image.open(paths[0]).size
    assert width <= 1300, f"{n_snrs} panels: {width} pixels wide"
