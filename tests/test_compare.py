"""`doabench compare`: paired differences over the episodes two results files share, pooled and per
cell, with a stratified paired bootstrap interval and a verdict; unpaired files are one-line errors."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from doabench.cli.main import main
from doabench.metrics import LAG_MAX_S, LAG_STEP_S, bootstrap_counts, lag_grid
from doabench.reporting import compare as cmp
from doabench.reporting import compare_report as report
from doabench.reporting.pairing import load_run

ROOT = Path(__file__).resolve().parents[1]
UP, EAST, NORTH = [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]


def _results(tracker: str, errors: list[float], task: str = "sim-grid", version: int = 2, seeds=None,
             cells: int = 2, frames: list[dict] | None = None, lag_at: float | None = None) -> dict:
    """A results file whose episode ``i`` has RMSAE ``errors[i]`` over 10 frames (8 voice-active)."""
    rows = []
    d = len(lag_grid(LAG_MAX_S, LAG_STEP_S))
    for i, e in enumerate(errors):
        row = {"episode": i, "task": f"sim-t60-{0.3 * (i % cells):g}-snr-5" if cells > 1 else task,
               "seed": (seeds or list(range(100, 100 + len(errors))))[i], "t60": 0.3 * (i % cells), "snr": 5.0,
               "recording": None, "rmsae_all": e, "rmsae_nonsilent": e, "mae": e, "within_10": float(e <= 10),
               "azimuth_mae": e, "n_frames": 10, "n_nonsilent": 8}
        if lag_at is not None:  # a moving talker: the curve's minimum at lag_at seconds
            row.update(lag_sse=[(k * LAG_STEP_S - lag_at) ** 2 + 1.0 for k in range(d)], lag_frames=8, lag_speed=20.0)
        rows.append(row)
    return {"schema": "doabench.results/1", "task": {"id": task, "version": version, "episodes_run": len(errors),
                                                     "episodes_total": len(errors), "source": {}},
            "tracker": {"id": tracker, "name": tracker.split(":")[0]}, "summary": {}, "environment": {},
            "scoring": {}, "episodes": rows, "frames": frames}


def _write(folder: Path, name: str, results: dict) -> Path:
    path = folder / name
    path.write_text(json.dumps(results))
    return path


BASE = [4.0, 6.0, 5.0, 7.0, 6.0, 8.0, 5.0, 9.0]


def test_paired_difference_pooled_and_per_cell(tmp_path, capsys):
    a = _write(tmp_path, "a.json", _results("mine", [e + 2.0 for e in BASE]))
    b = _write(tmp_path, "b.json", _results("cross3d:16x32", BASE))
    assert main(["compare", str(a), str(b), "--csv", str(tmp_path / "c.csv"), "--plot", str(tmp_path / "f")]) == 0
    out = capsys.readouterr().out
    assert "## `mine` against `cross3d:16x32`" in out and "8 episodes in common" in out
    comparison = cmp.compare(load_run(a), load_run(b))
    pooled = {r.metric.key: r for r in comparison.pooled}
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    assert pooled["rmsae_all"].diff == pytest.approx(rms(np.add(BASE, 2.0)) - rms(BASE))
    assert pooled["rmsae_all"].low > 0 and pooled["rmsae_all"].verdict == cmp.WORSE
    assert pooled["mae"].diff == pytest.approx(2.0) and pooled["mae"].low == pytest.approx(2.0)
    # a share within N deg is better when higher: mine has fewer episodes within 10 deg
    assert pooled["within_10"].diff <= 0 and pooled["within_10"].verdict in (cmp.WORSE, cmp.TIE)
    assert {r.scope for r in comparison.cells} == {"sim-t60-0-snr-5", "sim-t60-0.3-snr-5"}
    assert all(r.n_episodes == 4 for r in comparison.cells)
    assert "### Per cell" in out and "(T60 0.3 s, SNR 5 dB)" in out
    rows = list(csv.DictReader((tmp_path / "c.csv").open()))
    assert {r["scope"] for r in rows} == {"pooled", "sim-t60-0-snr-5", "sim-t60-0.3-snr-5"}
    assert rows[0]["metric"] == "rmsae_all" and rows[0]["verdict"] == "worse"
    assert (tmp_path / "f.png").stat().st_size > 0 and (tmp_path / "f.pdf").is_file()
    # the other way round: better, and a tie against itself
    swapped = cmp.compare(load_run(b), load_run(a))
    assert swapped.pooled[0].verdict == cmp.BETTER
    same = cmp.compare(load_run(b), load_run(_write(tmp_path, "b2.json", _results("other", BASE))))
    assert same.pooled[0].diff == 0 and same.pooled[0].verdict == cmp.TIE


def test_bootstrap_is_stratified_by_cell():
    strata = [np.array([0, 2, 4]), np.array([1, 3])]
    counts = bootstrap_counts(strata, 5, n_resamples=200, seed=1)
    assert counts.shape == (200, 5)
    assert np.all(counts[:, [0, 2, 4]].sum(1) == 3) and np.all(counts[:, [1, 3]].sum(1) == 2)


def test_only_shared_episodes_are_paired(tmp_path, capsys):
    """A run of the first N episodes pairs with the full run over those N."""
    short = _results("short", BASE[:4])
    short["task"]["episodes_run"] = 4
    a, b = _write(tmp_path, "a.json", short), _write(tmp_path, "b.json", _results("full", BASE))
    assert main(["compare", str(a), str(b)]) == 0
    out = capsys.readouterr().out
    assert "4 episodes in common (of 4 and 8)" in out


@pytest.mark.parametrize("change, words", [
    (lambda r: r["task"].update(version=1), "different task versions have different episodes"),
    (lambda r: r["task"].update(id="sim-pauses"), "only runs of the same task share episodes"),
    (lambda r: r["episodes"][0].update(seed=7), "and 7 in"),
    (lambda r: [e.update(episode=e["episode"] + 100) for e in r["episodes"]], "no episode in common"),
    (lambda r: r.update(episodes=[]), "has no per-episode rows"),
    (lambda r: r.update(schema="other"), "is not a doabench results file"),
])
def test_unpaired_files_are_one_line_errors(tmp_path, capsys, change, words):
    other = _results("b", BASE)
    change(other)
    a, b = _write(tmp_path, "a.json", _results("a", BASE)), _write(tmp_path, "b.json", other)
    assert main(["compare", str(a), str(b)]) == 2
    err = capsys.readouterr().err
    assert words in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_bad_options_are_one_line_errors(tmp_path, capsys):
    a = _write(tmp_path, "a.json", _results("a", BASE))
    for argv, words in ((["compare", str(a)], "needs two or more results files"),
                        (["compare", str(a), str(a), "--hold", "x"], "--hold takes whole numbers"),
                        (["compare", str(a), str(tmp_path / "none.json")], "does not exist"),
                        (["compare", str(a), str(a)], "nothing to compare"),
                        (["compare", str(a), str(a), "--csv", str(a)], "is also an input"),
                        (["compare", str(a), str(_write(tmp_path, "b.json", _results("b", BASE))), "--silence"],
                         "need per-frame estimates")):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert words in err and len(err.strip().splitlines()) == 1, err


def test_lag_is_compared_where_present(tmp_path):
    a = _write(tmp_path, "a.json", _results("late", BASE, lag_at=0.5))
    b = _write(tmp_path, "b.json", _results("prompt", BASE, lag_at=0.0))
    lag = next(r for r in cmp.compare(load_run(a), load_run(b)).pooled if r.metric.key == "lag_s")
    assert (lag.a, lag.b, lag.diff) == pytest.approx((0.5, 0.0, 0.5)) and lag.verdict == cmp.WORSE
    # files without lag rows (static sources, older files) have no lag row
    plain = cmp.compare(load_run(_write(tmp_path, "c.json", _results("c", BASE))), load_run(b))
    assert "lag_s" not in {r.metric.key for r in plain.pooled}


def _frames_results(tracker: str, estimates: list[list[list[float]]]) -> dict:
    """One cell, an episode per estimate list; the truth of every episode is UP, UP, EAST, NORTH and
    voice activity off, on, off, on (an error of 90 deg before the first voice, then the oracle's)."""
    truth, vad = [UP, UP, EAST, NORTH], [False, True, False, True]
    frames = [{"times": [0, 1, 2, 3], "estimates": est, "truth": truth, "vad": vad} for est in estimates]
    r = _results(tracker, [1.0] * len(estimates), cells=1, frames=frames)
    return r


def test_silence_breakdown_and_hold_the_truth(tmp_path, capsys):
    # errors 90 (before any voice), 0 (voiced), 90 (silent, truth moved), 0 (voiced)
    stay = _write(tmp_path, "stay.json", _frames_results("stay", [[EAST, UP, UP, NORTH]] * 2))
    perfect = _write(tmp_path, "perfect.json", _frames_results("perfect", [[UP, UP, EAST, NORTH]] * 2))
    assert main(["compare", str(stay), str(perfect), "--silence", "--hold", "1"]) == 0
    out = capsys.readouterr().out
    assert "| before the first voice | 2 | 90.00 | 0.50 |" in out, out
    assert "| 1-2 | 2 | 90.00 | 0.50 |" in out
    assert "| after the first voice (all but the row above) | 6 | 51.96 | 0.50 |" in out
    # the oracle: 90 (nothing heard yet), 0, 90 (up -> east), 0
    assert "RMSAE all frames 63.64 deg" in out
    rows = {r.metric.key: r for r in cmp.compare(load_run(stay), load_run(perfect), silence=True,
                                                 holds=[1]).pooled}
    assert rows["rmsae_before_first_voice"].a == pytest.approx(90.0) and rows["rmsae_before_first_voice"].b == 0
    assert rows["median"].a == pytest.approx(0.0) and rows["p90"].b == pytest.approx(0.0)
    # held after one silent frame, frame 2 repeats frame 1 (UP): error 90 against the truth EAST
    assert rows["rmsae_all_hold_1"].a == pytest.approx(float(np.sqrt((90 ** 2 * 2) / 4)))
    # one file with --silence: the breakdown only
    assert main(["compare", str(stay), "--silence", "--hold", "1"]) == 0
    out = capsys.readouterr().out
    assert "## Where the error of `stay` is" in out and "against" not in out
    assert "Held after 1 silent frames: RMSAE all frames 63.64 deg." in out


def test_shipped_results_pool_as_the_leaderboards_do(capsys):
    """On the committed results the pooled values are the files' own summary."""
    a, b = ROOT / "results" / "sim-fan__gcc-cnn1d__paper.json", ROOT / "results" / "sim-fan__cross3d_16x32__paper.json"
    if not (a.is_file() and b.is_file()):
        pytest.skip("shipped results not present")
    c = cmp.compare(load_run(a), load_run(b), n_resamples=200)
    ra, rb = (json.loads(p.read_text())["summary"] for p in (a, b))
    pooled = {r.metric.key: r for r in c.pooled}
    assert pooled["rmsae_all"].a == pytest.approx(ra["rmsae_all"]) and pooled["rmsae_all"].b == pytest.approx(rb["rmsae_all"])
    assert pooled["rmsae_nonsilent"].a == pytest.approx(ra["rmsae_nonsilent"])
    assert pooled["mae"].a == pytest.approx(ra["pooled"]["mae"])


def test_two_renderings_of_the_same_scenes_pair_by_seed(tmp_path, capsys):
    # sim-walk (builtin) and sim-walk-pra (pyroomacoustics) draw the same scenes: other task ids and
    # episode indices, the same seeds; --by-seed pairs them, without it they are refused
    builtin = _results("srp-max:32x64", BASE, task="sim-walk", version=1)
    pra = _results("srp-max:32x64", [e + 1.0 for e in BASE[:4]], task="sim-walk-pra", version=1)
    for i, row in enumerate(pra["episodes"]):  # the first episodes of each cell, renumbered
        row["episode"] = 100 + i
    a, b = _write(tmp_path, "walk.json", builtin), _write(tmp_path, "walk-pra.json", pra)
    assert main(["compare", str(a), str(b)]) == 2
    assert "only runs of the same task" in capsys.readouterr().err
    assert main(["compare", str(a), str(b), "--by-seed"]) == 0
    assert "4 episodes in common" in capsys.readouterr().out
    comparison = cmp.compare(load_run(b), load_run(a), by_seed=True)
    assert comparison.pooled[0].diff == pytest.approx(
        float(np.sqrt(np.mean(np.square(np.add(BASE[:4], 1.0))))) - float(np.sqrt(np.mean(np.square(BASE[:4])))))
    no_shared = _results("srp-max:32x64", BASE, task="sim-walk-pra", seeds=list(range(900, 908)))
    with pytest.raises(Exception, match="share no scene seed"):
        cmp.compare(load_run(a), load_run(_write(tmp_path, "other.json", no_shared)), by_seed=True)


def _with_bands(results: dict, fast_episodes: int = 1) -> dict:
    """Speed bands in every row: the voice-active frames below 5 deg/s, and in the first
    ``fast_episodes`` episodes 3 of them above 30 deg/s, with an error growing with the RMSAE."""
    for i, row in enumerate(results["episodes"]):
        fast = i < fast_episodes
        row["speed_bands"] = {"<5": [row["rmsae_all"] ** 2 * (5 if fast else 8), 5 if fast else 8], "5-15": [0.0, 0],
                              "15-30": [0.0, 0], ">30": [(row["rmsae_all"] + 1.0) ** 2 * 3 if fast else 0.0,
                                                         3 if fast else 0]}
    return results


def test_a_line_backed_by_too_few_episodes_gets_no_verdict(tmp_path, capsys):
    """Eight paired episodes, one with frames above 30 deg/s: the RMSAE line has its verdict, the
    >30 deg/s line says how many episodes back it and gives no verdict and no interval, in the
    Markdown, the CSV and the forest plot alike."""
    a = _write(tmp_path, "a.json", _with_bands(_results("mine", [e + 2.0 for e in BASE], cells=1)))
    b = _write(tmp_path, "b.json", _with_bands(_results("other", BASE, cells=1)))
    c = cmp.compare(load_run(a), load_run(b))
    pooled = {r.metric.key: r for r in c.pooled}
    assert pooled["rmsae_all"].n_contributing == 8 and pooled["rmsae_all"].verdict == cmp.WORSE
    fast = pooled["rmsae_speed_>30"]
    assert fast.n_contributing == 1 and fast.verdict == cmp.TOO_FEW and fast.diff > 0
    assert fast.low == pytest.approx(fast.high)  # one episode: every resample holds the same value
    assert pooled["rmsae_speed_15-30"].n_contributing == 0 and pooled["rmsae_speed_15-30"].verdict == cmp.TOO_FEW
    assert main(["compare", str(a), str(b), "--csv", str(tmp_path / "c.csv"), "--plot", str(tmp_path / "f")]) == 0
    out = capsys.readouterr().out
    assert "| metric | n |" in out
    line = next(x for x in out.splitlines() if x.startswith("| RMSAE voice-active, truth moving >30 deg/s"))
    assert line.endswith(f"| 1 | {report._fmt(fast.a, 'deg')} | {report._fmt(fast.b, 'deg')} | {report._fmt(fast.diff, 'deg', True)} "
                         "| too few episodes |"), line
    assert "[" not in line and "worse" not in line
    rows = {r["metric"]: r for r in csv.DictReader((tmp_path / "c.csv").open())}
    assert rows["rmsae_speed_>30"]["verdict"] == "too few episodes" and rows["rmsae_speed_>30"]["n_contributing"] == "1"
    assert rows["rmsae_all"]["n_contributing"] == "8"
    # the forest plot: the RMSAE line in its verdict's colour with its interval, the other hollow and bare
    import matplotlib.pyplot as plt

    fig = report.forest_figure([c], metrics=("rmsae_all", "rmsae_speed_>30"))
    left, right = fig.axes[:2]
    assert len(left.containers) == 1 and right.containers == []
    hollow = [ln for ln in right.lines if ln.get_marker() not in (None, "None", "")]
    assert len(hollow) == 1 and hollow[0].get_markerfacecolor() == "none"
    assert hollow[0].get_color() not in report.VERDICT_COLOURS.values()
    plt.close(fig)


def test_the_episodes_a_verdict_needs_can_be_set_and_cells_count_too_few(tmp_path, capsys):
    """Three episodes are too few by default; --min-episodes 3 allows a verdict on them. Cells of 4
    episodes are too few for a verdict, and the cell tally says so."""
    a = _write(tmp_path, "a.json", _results("mine", [e + 2.0 for e in BASE[:3]], cells=1))
    b = _write(tmp_path, "b.json", _results("other", BASE[:3], cells=1))
    assert cmp.compare(load_run(a), load_run(b)).pooled[0].verdict == cmp.TOO_FEW
    assert cmp.compare(load_run(a), load_run(b), min_episodes=3).pooled[0].verdict == cmp.WORSE
    assert main(["compare", str(a), str(b), "--min-episodes", "3"]) == 0
    assert "| RMSAE all frames (deg) | 3 |" in capsys.readouterr().out
    assert main(["compare", str(a), str(b), "--min-episodes", "1"]) == 2
    err = capsys.readouterr().err
    assert "--min-episodes must be at least 2" in err and len(err.strip().splitlines()) == 1
    grid_a = _write(tmp_path, "ga.json", _results("mine", [e + 2.0 for e in BASE]))
    grid_b = _write(tmp_path, "gb.json", _results("other", BASE))
    grid = cmp.compare(load_run(grid_a), load_run(grid_b))
    assert all(r.verdict == cmp.TOO_FEW for r in grid.cells) and grid.pooled[0].verdict == cmp.WORSE
    assert report.cell_summary(grid) == ("better in 0, worse in 0, no significant difference in 0, too few episodes in 2 "
                                      "of 2 cells")


@pytest.mark.parametrize("per_cell", [1, 2])
def test_cells_of_one_or_two_episodes_are_not_resampled_within_themselves(tmp_path, capsys, per_cell):
    """Twelve cells of one (or two) paired episodes each: drawn within each cell, every resample
    repeats the same episodes and the interval has (nearly) no width. The pooled lines draw the
    episodes across the task instead, so the interval holds the spread between episodes, and the
    report, the CSV and the forest plot say so."""
    rng = np.random.default_rng(3)
    base = list(rng.uniform(5.0, 30.0, 12 * per_cell))
    gain = list(rng.normal(-3.0, 6.0, 12 * per_cell))  # differences that vary from episode to episode
    a = _write(tmp_path, "a.json", _results("mine", [max(e + g, 0.5) for e, g in zip(base, gain)], cells=12))
    b = _write(tmp_path, "b.json", _results("other", base, cells=12))
    c = cmp.compare(load_run(a), load_run(b))
    headline = c.pooled[0]
    assert headline.metric.key == "rmsae_all" and headline.bootstrap == cmp.ACROSS
    # the interval of the unstratified paired bootstrap over all episodes, not a stratified one
    everything = np.arange(12 * per_cell)
    across = cmp.compare_scope(c.pairing, headline.metric, everything, [everything], "pooled", cmp.N_RESAMPLES, 0)
    assert (headline.low, headline.high) == pytest.approx((across.low, across.high))
    assert headline.high - headline.low > 1.0  # a real spread, not a point
    assert all(r.verdict == cmp.TOO_FEW for r in c.cells)
    assert any("draw episodes across the whole task" in n for n in c.notes)
    assert main(["compare", str(a), str(b), "--csv", str(tmp_path / "c.csv")]) == 0
    out = capsys.readouterr().out
    assert "draw episodes across the whole task" in out
    rows = list(csv.DictReader((tmp_path / "c.csv").open()))
    assert rows[0]["scope"] == "pooled" and rows[0]["bootstrap"] == cmp.ACROSS
    import matplotlib.pyplot as plt

    fig = report.forest_figure([c])
    assert "drawn across cells" in fig._suptitle.get_text()
    plt.close(fig)


def test_cells_of_five_episodes_or_more_are_resampled_within_themselves(tmp_path):
    """Two cells of five paired episodes: the pooled lines draw within each cell (stratified)."""
    a = _write(tmp_path, "a.json", _results("mine", [e + 2.0 for e in BASE + BASE[:2]]))
    b = _write(tmp_path, "b.json", _results("other", BASE + BASE[:2]))
    c = cmp.compare(load_run(a), load_run(b))
    assert c.pooled[0].bootstrap == cmp.STRATIFIED and not any("across the whole task" in n for n in c.notes)
    assert {r.bootstrap for r in c.cells} == {cmp.ACROSS}
