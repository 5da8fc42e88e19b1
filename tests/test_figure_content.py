"""The content fingerprint of a figure: what it shows (titles, labels, lines, bands, legends), not
how it is rendered; written into every PNG doabench saves and read back from it."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from doabench.reporting import plots
from doabench.reporting.figure_content import (CONTENT_KEY, content_fingerprint, figure_content,
                                               png_fingerprint)


def _figure(y: list[float], label: str = "srp-max:8x16", colour: str = "tab:blue", size: tuple[float, float] = (5, 3)):
    plt = plots._pyplot()
    fig, ax = plt.subplots(figsize=size)
    ax.plot([0.0, 0.3, 0.9], y, label=label, color=colour, marker="o")
    ax.fill_between([0.0, 0.3, 0.9], np.array(y) - 1, np.array(y) + 1, alpha=0.2)
    ax.axhline(0.0, color="k")
    ax.set_title("SNR = 5 dB")
    ax.set_xlabel("T60 [s]")
    ax.set_ylabel("RMSAE [deg]")
    ax.legend()
    fig.suptitle("sim-grid")
    return fig


def test_the_fingerprint_follows_what_is_drawn_not_how() -> None:
    base = _figure([10.0, 12.0, 20.0])
    fingerprint = content_fingerprint(base)
    assert len(fingerprint) == 64 and int(fingerprint, 16) >= 0
    # another size, a draw, a tight layout: the same content
    assert content_fingerprint(_figure([10.0, 12.0, 20.0], size=(9, 6))) == fingerprint
    base.canvas.draw()
    base.tight_layout()
    assert content_fingerprint(base) == fingerprint
    # below the rounding (1e-6): the same; any drawn difference: another fingerprint
    assert content_fingerprint(_figure([10.0 + 1e-9, 12.0, 20.0])) == fingerprint
    for other in (_figure([10.0 + 1e-4, 12.0, 20.0]), _figure([10.0, 12.0, 20.0], label="srp-max:16x32"),
                  _figure([10.0, 12.0, 20.0], colour="black"), _figure([10.0, 12.0, float("nan")])):
        assert content_fingerprint(other) != fingerprint
    retitled = _figure([10.0, 12.0, 20.0])
    retitled.axes[0].set_xlabel("T60 [ms]")
    assert content_fingerprint(retitled) != fingerprint
    plots._pyplot().close("all")


def test_the_content_lists_titles_labels_lines_bands_and_legends() -> None:
    content = figure_content(_figure([10.0, 12.0, float("nan")]))
    assert content["suptitle"] == "sim-grid"
    [ax] = content["axes"]
    assert ax["titles"][1] == "SNR = 5 dB" and ax["xlabel"] == "T60 [s]" and ax["ylabel"] == "RMSAE [deg]"
    line = ax["lines"][0]
    assert line["label"] == "srp-max:8x16" and line["y"] == [10.0, 12.0, None] and line["colour"] == "#1f77b4ff"
    assert ax["lines"][1]["label"] == ""  # matplotlib's own _child names are no labels
    assert len(ax["collections"]) == 1 and ax["collections"][0]["paths"]  # the band's polygon
    assert ax["legend"] == ["srp-max:8x16"]
    plots._pyplot().close("all")


def test_save_figure_writes_the_fingerprint_into_the_png(tmp_path: Path) -> None:
    from PIL import Image

    fig = _figure([10.0, 12.0, 20.0])
    expected = content_fingerprint(fig)
    png, pdf = plots.save_figure(fig, tmp_path / "figure")
    assert png_fingerprint(png) == expected
    with Image.open(png) as image:
        assert image.text[CONTENT_KEY] == expected
    assert pdf.is_file()
    # written at another dpi: the pixels differ, the fingerprint does not
    fig = _figure([10.0, 12.0, 20.0])
    png2, _ = plots.save_figure(fig, tmp_path / "figure-dpi", dpi=60)
    assert png2.read_bytes() != png.read_bytes() and png_fingerprint(png2) == expected
    # a PNG that holds none
    Image.new("RGB", (4, 4)).save(tmp_path / "plain.png")
    assert png_fingerprint(tmp_path / "plain.png") is None


@pytest.mark.parametrize("name", ["rmsae-vs-t60", "maps", "conventions"])
def test_every_kind_of_figure_has_a_fingerprint_that_a_redraw_keeps(name: str) -> None:
    from doabench.arrays import get_array
    from test_plot_styles import _grid_results

    def build():
        if name == "rmsae-vs-t60":
            return plots.rmsae_vs_t60_figure([_grid_results("srp-max:8x16", 10.0), _grid_results("srp-max:4x8", 20.0)])
        if name == "maps":
            rng = np.random.default_rng(0)
            return plots.maps_figure({(4, 8): rng.random((4, 8)), (8, 16): rng.random((8, 16))},
                                     np.array([0.0, 1.0, 0.0]))
        return plots.conventions_figure(get_array("nao"), (8, 16))

    first = build()
    fingerprint = content_fingerprint(first)
    first.canvas.draw()  # colour bars and meshes get their colours when drawn
    assert content_fingerprint(first) == fingerprint == content_fingerprint(build())
    plots._pyplot().close("all")
