"""Comparing runs in figures: `plot episode A.json B.json`, `plot rmsae-vs-t60` on
per-cell results files, colour bars on maps."""
from __future__ import annotations

import json
from pathlib import Path

from doabench.cli.main import main
from test_leaderboard import _results


def _write(path: Path, results: dict) -> str:
    path.write_text(json.dumps(results))
    return str(path)


def test_plot_episode_compares_several_runs(tmp_path: Path, capsys) -> None:
    a = _write(tmp_path / "a.json", _results("srp-max:8x16", 30.0))
    b = _write(tmp_path / "b.json", _results("srp-kalman:32x64", 12.5))
    out = tmp_path / "cmp"
    assert main(["plot", "episode", a, b, "--episode", "1", "--no-render", "--out", str(out)]) == 0
    assert (tmp_path / "cmp.png").stat().st_size > 1000 and (tmp_path / "cmp.pdf").is_file()
    other_task = _write(tmp_path / "c.json", _results("srp-max", 5.0, "sim-demo", 2, 4))
    capsys.readouterr()
    assert main(["plot", "episode", a, other_task, "--episode", "1", "--no-render", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "compare runs of one task" in err and "\n" not in err


def test_rmsae_vs_t60_accepts_per_cell_results(tmp_path: Path) -> None:
    files = []
    for tracker, base in (("srp-max:8x16", 20.0), ("srp-kalman:32x64", 10.0)):
        for cell, shift in (("sim-t60-0.3-snr-30", 0.0), ("sim-t60-0.9-snr-30", 5.0)):
            r = _results(tracker, base + shift, cell, 2, 2)
            files.append(_write(tmp_path / f"{cell}__{tracker.replace(':', '_')}.json", r))
    from doabench.results.schema import load_results
    from doabench.reporting.plots import merge_cell_runs

    merged = merge_cell_runs([load_results(f) for f in files])
    assert len(merged) == 2 and all(len(m["cells"]) == 2 for m in merged)  # one line per tracker, two T60s
    out = tmp_path / "t60"
    assert main(["plot", "rmsae-vs-t60", *files, "--metric", "rmsae_all", "--out", str(out)]) == 0
    assert (tmp_path / "t60.png").stat().st_size > 1000


def test_maps_have_a_colour_bar(tmp_path: Path) -> None:
    import numpy as np

    from doabench.reporting.plots import plot_maps

    m = np.random.default_rng(0).random((8, 16))
    captured = {}
    import doabench.reporting.plots as plots

    original = plots.save_figure

    def spy(fig, out, *a, **k):
        captured["axes"] = len(fig.axes)
        return original(fig, out, *a, **k)

    plots.save_figure = spy
    try:
        plot_maps({(8, 16): m, (4, 8): m[::2, ::2]}, np.array([0.0, 1.0, 0.0]), tmp_path / "maps")
    finally:
        plots.save_figure = original
    assert captured["axes"] == 4  # two maps, two colour bars
