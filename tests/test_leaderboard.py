"""Leaderboards and plots: deterministic tables with CIs, provenance and published rows; figures
written as PNG and PDF. Built from small synthetic results files so the tests stay fast."""
from __future__ import annotations

import copy
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from doabench.cli.main import main as cli
from doabench.errors import InputError
from doabench.reporting.leaderboard import build_leaderboards, stale_files
from doabench.results.ranking import load_runs

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "leaderboards" / "locata-paper-table2.csv"


def _results(tracker: str, rmsae: float, task: str = "sim-grid", episodes_run: int = 2, total: int = 2,
             recordings: bool = False, scored_episodes: int = 1) -> dict:
    """A minimal results dict in the runner's schema, two episodes, grid cells for sim-grid. Only the
    first ``scored_episodes`` episodes have scored frames, each scoring the summary's RMSAEs, so the
    pooled RMSAEs are what the rows say (and with 3 of them the file's interval is shown)."""
    rng = np.random.default_rng(abs(hash(tracker)) % 1000)
    times = (np.arange(5) * 3072 + 2048) / 16000
    truth = np.tile([[1.0, 0.0, 0.0]], (5, 1))
    frames = [{"times": times.tolist(), "estimates": (truth + 0.1 * rng.standard_normal((5, 3))).tolist(),
               "truth": truth.tolist(), "vad": [1, 1, 0, 1, 1]} for _ in range(episodes_run)]
    rows = [{"episode": i, "task": "sim-t60-0.3-snr-30" if i == 0 else "sim-t60-0.9-snr-5", "seed": 100 + i,
             "t60": 0.3 if i == 0 else 0.9, "snr": 30.0 if i == 0 else 5.0,
             "recording": i + 1 if recordings else None,
             "rmsae_all": rmsae + (0 if i < scored_episodes else i),
             "rmsae_nonsilent": rmsae - 1 + (0 if i < scored_episodes else i),
             "n_frames": 5 if i < scored_episodes else 0, "n_nonsilent": 4 if i < scored_episodes else 0}
            for i in range(episodes_run)]
    pooled = {"rmsae_all": rmsae, "rmsae_nonsilent": rmsae - 1, "mae": rmsae / 2, "median": rmsae / 3,
              "p90": rmsae * 1.5, "within_5": 0.1, "within_10": 0.5, "within_20": 0.8, "within_30": 0.9,
              "azimuth_mae": rmsae / 4, "n_frames": 10, "n_nonsilent": 8, "n_episodes": episodes_run}
    cells = {}
    if task == "sim-grid":
        cells = {"sim-t60-0.3-snr-30": {"t60": 0.3, "snr": 30.0, "rmsae_all": rmsae - 2, "rmsae_nonsilent": rmsae - 3,
                                        "rmsae_all_ci95": [rmsae - 4, rmsae], "rmsae_nonsilent_ci95": [rmsae - 5, rmsae - 1],
                                        "n_episodes": 1},
                 "sim-t60-0.9-snr-5": {"t60": 0.9, "snr": 5.0, "rmsae_all": rmsae + 2, "rmsae_nonsilent": rmsae + 1,
                                       "rmsae_all_ci95": [rmsae, rmsae + 4], "rmsae_nonsilent_ci95": [rmsae - 1, rmsae + 3],
                                       "n_episodes": 1}}
    name, _, spec = tracker.partition(":")
    return {
        "schema": "doabench.results/1",
        "task": {"id": task, "version": 0, "kind": "simulated", "gym_id": f"doabench/{task}-v0", "base_seed": 7,
                 "episodes_run": episodes_run, "episodes_total": total,
                 "source": {"simulator": "builtin", "speech": {"corpus": "librispeech", "subset": "test-other"}}},
        "tracker": {"id": tracker, "name": name, "version": "1", "spec": spec or None, "causal": True,
                    "features": ["srp"], "resolution": spec or "16x32", "parameters": 0,
                    "receptive_field_frames": 1, "weights_hash": None, "options": {}},
        "causal": True,
        "features": {"kinds": ["srp"], "resolution": spec if re.fullmatch(r"\d+x\d+", spec) else "16x32",
                     "delays": "nearest",
                     "frame": {"window": 4096, "hop": 3072, "fs": 16000}},
        "environment": {"doabench": "0.1.0", "git": {"commit": "a" * 40, "dirty": False}, "python": "3.11.7",
                        "torch": "2.13.0+cpu", "numpy": "2.0", "cpu": "Test CPU", "cpu_count": 2, "device": "cpu",
                        "date": "2026-01-01T00:00:00+00:00"},
        "summary": {"rmsae_all": rmsae, "rmsae_nonsilent": rmsae - 1, "rmsae_all_ci95": [rmsae - 2, rmsae + 2],
                    "rmsae_nonsilent_ci95": [rmsae - 3, rmsae + 1], "pooled": pooled, "episode_mean": pooled},
        "cells": cells, "wall_time_s": 60.0, "episodes": rows, "frames": frames,
    }


@pytest.fixture
def results_dir(tmp_path: Path) -> Path:
    d = tmp_path / "results"
    d.mkdir()
    for tracker, value in (("srp-max:8x16", 30.0), ("srp-kalman:32x64", 12.5)):
        (d / f"sim-grid__{tracker.replace(':', '_')}.json").write_text(
            json.dumps(_results(tracker, value, episodes_run=3, total=3, scored_episodes=3)))
    (d / "sim-demo__srp-max.json").write_text(json.dumps(_results("srp-max", 5.0, "sim-demo", 1, 4)))
    (d / "locata-3__srp-max.json").write_text(json.dumps(_results("srp-max", 20.0, "locata-3", 2, 2, True)))
    (d / "notes.json").write_text(json.dumps({"something": "else"}))  # not a results file: skipped, named
    return d


def test_tables_ranked_with_cis_provenance_and_cells(results_dir: Path) -> None:
    files = build_leaderboards(results_dir, [REFERENCE], command="doabench leaderboard")
    assert {"sim-grid.md", "sim-grid.csv", "sim-grid-cells.csv", "sim-demo.md", "locata-3.md", "locata-1.md",
            "summary.md"} <= set(files)
    page = files["sim-grid.md"]
    # ranked by RMSAE over all frames, with bootstrap intervals on every RMSAE
    assert page.index("`srp-kalman:32x64`") < page.index("`srp-max:8x16`")
    assert "12.50 [10.50, 14.50]" in page and "11.50 [9.50, 13.50]" in page
    # per-cell T60 x SNR tables per tracker
    assert "### `srp-max:8x16` (R2)" in page and "| 0.9 |" in page and "SNR 30 dB, non-silent" in page
    # provenance footnotes: file and its hash, commit, seeds, hardware, date, reproduce command
    assert "sim-grid__srp-max_8x16.json` (sha256 `" in page and "commit `aaaaaaaaaaaa`" in page
    assert "base seed 7" in page and "Test CPU ×2" in page and "2026-01-01T00:00:00+00:00" in page
    assert "`doabench run --tracker srp-max:8x16 --task sim-grid --librispeech LIBRISPEECH_ROOT`" in page
    assert "Regenerate with `doabench leaderboard`" in page
    # partial runs are ranked apart, with their coverage, and reproducible with --episodes
    demo = files["sim-demo.md"]
    assert "No complete run of this task yet" in demo and "## Partial runs (ranked apart from complete runs)" in demo
    assert "1 of 4 episodes (the first 1)" in demo and "--episodes 1" in demo
    cells = files["sim-grid-cells.csv"].splitlines()
    assert cells[0].startswith("tracker,t60,snr") and len(cells) == 5


def test_published_rows_are_marked_and_separate(results_dir: Path) -> None:
    files = build_leaderboards(results_dir, [REFERENCE])
    page = files["locata-3.md"]
    published = page.split("## Published reference rows (not reproduced)")[1]
    assert "Cross3D (SRP-PHAT maps, 32x64) | 12.43 | 8.36 | 7.69 | 9.49 | published, not reproduced" in published
    ours = page.split("## Published")[0]
    assert "Cross3D" not in ours and "`srp-max:16x32`" in ours  # the alias srp-max shown under its canonical id
    assert "### Per recording" in ours and "| `srp-max:16x32` | 20.00 | 21.00 | — | 20.50 | R1 |" in ours
    csv_lines = files["locata-3.csv"].splitlines()
    assert csv_lines[1].startswith("doabench run,1,locata-3")
    assert sum(line.startswith("published,") for line in csv_lines) == 9
    # LOCATA tasks without doabench runs still show the published rows
    assert "No doabench results for this task yet" in files["locata-1.md"]


def test_regeneration_is_byte_identical_and_check_detects_staleness(results_dir: Path, tmp_path: Path,
                                                                     capsys) -> None:
    out = tmp_path / "boards"
    args = ["leaderboard", "--results", str(results_dir), "--out", str(out), "--reference", str(REFERENCE)]
    assert cli(args) == 0
    first = {p.name: p.read_bytes() for p in out.iterdir()}
    assert cli(args) == 0
    assert {p.name: p.read_bytes() for p in out.iterdir()} == first
    assert cli(args + ["--check"]) == 0
    changed = _results("srp-max:8x16", 3.0)
    (results_dir / "sim-grid__srp-max_8x16.json").write_text(json.dumps(changed))
    capsys.readouterr()
    assert cli(args + ["--check"]) == 1
    assert "sim-grid.md" in capsys.readouterr().out


def test_bad_results_file_is_a_one_line_error(results_dir: Path, tmp_path: Path, capsys) -> None:
    (results_dir / "broken.json").write_text("{not json")
    with pytest.raises(InputError, match="broken.json is not valid JSON"):
        load_runs(results_dir)
    assert cli(["leaderboard", "--results", str(results_dir), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("doabench leaderboard: error:") and "\n" not in err
    assert cli(["leaderboard", "--results", str(tmp_path / "missing"), "--out", str(tmp_path / "o")]) == 2


def test_committed_leaderboards_match_committed_results() -> None:
    """leaderboards/ is generated from results/: a new or changed results file needs a regeneration."""
    import os

    here = os.getcwd()
    os.chdir(ROOT)  # tables show paths relative to the working directory
    try:
        files = build_leaderboards("results", ["leaderboards/locata-paper-table2.csv"],
                                   command="doabench leaderboard --results results --out leaderboards")
        stale = stale_files(files, "leaderboards")
    finally:
        os.chdir(here)
    assert not stale, f"stale leaderboards {stale}: run `doabench leaderboard` from the repository root"


def test_plots_write_png_and_pdf(results_dir: Path, tmp_path: Path) -> None:
    grid = [str(results_dir / "sim-grid__srp-max_8x16.json"), str(results_dir / "sim-grid__srp-kalman_32x64.json")]
    out = tmp_path / "fig"
    assert cli(["plot", "rmsae-vs-t60", *grid, "--snr", "30", "--metric", "rmsae_all", "--out", str(out / "t60")]) == 0
    assert cli(["plot", "episode", grid[0], "--episode", "1", "--no-render", "--out", str(out / "ep")]) == 0
    log = tmp_path / "runs" / "demo" / "log.csv"
    log.parent.mkdir(parents=True)
    log.write_text("epoch,phase_snr,batch_size,lr,train_loss,val_loss,val_rmsae_all,val_rmsae_nonsilent\n"
                   "1,30,5,0.001,0.5,0.6,40,35\n2,30,5,0.001,0.3,0.4,30,25\n")
    assert cli(["plot", "training", str(log), "--out", str(out / "train")]) == 0
    for stem in ("t60", "ep", "train"):
        png, pdf = out / f"{stem}.png", out / f"{stem}.pdf"
        assert png.read_bytes()[:4] == b"\x89PNG" and pdf.read_bytes()[:4] == b"%PDF"
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # atomic writes leave no temporaries


def test_plot_errors_are_one_line(results_dir: Path, tmp_path: Path, capsys) -> None:
    f = str(results_dir / "sim-grid__srp-max_8x16.json")
    assert cli(["plot", "rmsae-vs-t60", f, "--snr", "20", "--out", str(tmp_path / "x")]) == 2
    assert "no cells with SNR 20 dB" in capsys.readouterr().err
    assert cli(["plot", "episode", f, "--episode", "9", "--no-render", "--out", str(tmp_path / "x")]) == 2
    assert "episode 9 is not in the results file" in capsys.readouterr().err
    no_frames = copy.deepcopy(_results("srp-max", 5.0))
    no_frames["frames"] = None
    (tmp_path / "nf.json").write_text(json.dumps(no_frames))
    assert cli(["plot", "episode", str(tmp_path / "nf.json"), "--episode", "0", "--no-render"]) == 2
    assert "--no-frames" in capsys.readouterr().err


def test_plot_maps_and_rendered_episode(tmp_path: Path) -> None:
    """Maps at two resolutions and an episode plot with maxima re-rendered from the task (embedded speech)."""
    import doabench

    doabench.register_task(ROOT / "docs" / "examples" / "quiet-office.toml")
    out = tmp_path / "maps"
    assert cli(["plot", "maps", "--task", "quiet-office", "--episode", "0", "--frame", "6",
                "--resolutions", "4x8,8x16", "--out", str(out)]) == 0
    assert (tmp_path / "maps.png").stat().st_size > 1000 and (tmp_path / "maps.pdf").is_file()
    results = doabench.run(tracker="srp-max:4x8", task="quiet-office", episodes=1, progress=False)
    path = tmp_path / "r.json"
    path.write_text(json.dumps(results, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))
    assert cli(["plot", "episode", str(path), "--episode", "0", "--out", str(tmp_path / "ep")]) == 0
    assert (tmp_path / "ep.png").is_file()


def test_the_reproduce_command_takes_its_flags_from_the_task_kind(monkeypatch):
    """The corpus flags come from the kind's options (``Options.reproduce_flags``): LOCATA's root,
    split and VAD, LibriSpeech's root and the simulator, a plug-in kind's own, nothing for a kind
    that is not installed."""
    import dataclasses

    import doabench.envs.sources as sources
    from doabench.reporting.leaderboard import reproduce_command

    def results(kind, source):
        return {"task": {"id": "t", "kind": kind, "source": source}, "tracker": {"id": "srp-max:8x16"}}

    locata = reproduce_command(results("locata", {"split": "eval", "vad": "corpus", "locata_task": 3}))
    assert locata.endswith("--task t --locata-root LOCATA_ROOT --split eval --vad corpus")
    assert reproduce_command(results("locata", {"split": "dev", "vad": "webrtc"})).endswith("--locata-root LOCATA_ROOT")
    simulated = {"speech": {"corpus": "librispeech"}, "simulator": "pyroomacoustics"}
    assert reproduce_command(results("simulated", simulated)).endswith(
        "--librispeech LIBRISPEECH_ROOT --backend pyroomacoustics")
    assert reproduce_command(results("dataset", {"file": "x.h5"})).endswith("--task t")

    @dataclasses.dataclass(frozen=True)
    class ToneOptions:
        tone_root: str | None = None

        @staticmethod
        def reproduce_flags(source):
            return ["--tone-root TONES_ROOT"] if source.get("recorded") else []

    def tones(spec, tone_root=None):
        raise AssertionError("not built for a leaderboard")

    tones.Options = ToneOptions
    monkeypatch.setitem(sources.TASK_KINDS._entries, "tones", tones)  # registered for this test only
    assert reproduce_command(results("tones", {"recorded": True})).endswith("--task t --tone-root TONES_ROOT")
    assert reproduce_command(results("not-installed", {"recorded": True})).endswith("--task t")


def test_several_results_folders_are_read_together(results_dir: Path, tmp_path: Path, capsys) -> None:
    """Two --results folders give one board with the runs of both, and the tables' command names both."""
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "sim-grid__mine.json").write_text(json.dumps(_results("mine", 20.0)))
    out = tmp_path / "boards"
    assert cli(["leaderboard", "--results", str(results_dir), "--results", str(mine), "--out", str(out)]) == 0
    page = (out / "sim-grid.md").read_text()
    assert "`mine:16x32`" in page and "`srp-kalman:32x64`" in page and "`srp-max:8x16`" in page
    assert page.index("`srp-kalman:32x64`") < page.index("`mine:16x32`") < page.index("`srp-max:8x16`")
    assert f"--results {results_dir} --results {mine}" in page
    # a folder given twice (another spelling) is read once
    again = build_leaderboards([results_dir, results_dir / ".." / "results"])
    assert again == build_leaderboards(results_dir)


def test_one_configuration_in_two_folders_is_shown_once_per_folder(results_dir: Path, tmp_path: Path) -> None:
    """A configuration with a file in each folder is two rows, each naming its folder and its
    episodes (no refusal, no silent pick); a partial run of a configuration also in another folder
    is marked the same way and ranked apart; within one folder, files of one configuration stay one
    row with the others superseded."""
    import csv as csv_module

    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "rerun.json").write_text(json.dumps(_results("srp-max:8x16", 29.0)))  # 2 of 2 episodes: complete
    (mine / "quick.json").write_text(json.dumps(_results("srp-kalman:32x64", 5.0, episodes_run=1, total=3)))
    out = tmp_path / "boards"
    assert cli(["leaderboard", "--results", str(results_dir), "--results", str(mine), "--out", str(out)]) == 0
    page = (out / "sim-grid.md").read_text()
    ranked = page.split("## Partial runs")[0].split("## Per cell")[0]
    assert f"| 1 | `srp-kalman:32x64` (`{results_dir}`, 3 episodes) |" in ranked  # the partial one is not ranked here
    assert f"| 2 | `srp-max:8x16` (`{mine}`, 2 episodes) |" in ranked
    assert f"| 3 | `srp-max:8x16` (`{results_dir}`, 3 episodes) |" in ranked
    partial = page.split("## Partial runs (ranked apart from complete runs)")[1].split("## ")[0]
    assert f"| 1 | `srp-kalman:32x64` (`{mine}`, 1 of 3 episodes) | 1 of 3 episodes" in partial
    assert "## Superseded files" not in page
    rows = list(csv_module.DictReader((out / "sim-grid.csv").read_text().splitlines()))
    assert [(r["rank"], r["tracker"], Path(r["results_file"]).name) for r in rows] == [
        ("1", "srp-kalman:32x64", "sim-grid__srp-kalman_32x64.json"), ("2", "srp-max:8x16", "rerun.json"),
        ("3", "srp-max:8x16", "sim-grid__srp-max_8x16.json"), ("P1", "srp-kalman:32x64", "quick.json")]
    # a configuration in one folder only reads as before: no folder in its label
    assert "`srp-max:8x16` (" not in build_leaderboards(results_dir)["sim-grid.md"].split("## Per cell")[0]
    # within one folder, files of one configuration are still shown once and listed as superseded
    (results_dir / "rerun.json").write_text(json.dumps(_results("srp-max:8x16", 29.0)))
    assert "## Superseded files" in build_leaderboards(results_dir)["sim-grid.md"]


def test_a_partial_run_is_marked_and_ranked_apart_from_complete_runs(tmp_path: Path) -> None:
    """Partial runs say how many of the task's episodes they hold ("1 of 4 episodes") and are
    ranked among themselves, under the complete runs, whose ranks they never change, however good."""
    import csv as csv_module

    for name, rmsae, run in (("a", 20.0, 4), ("b", 25.0, 4), ("c", 3.0, 1), ("d", 10.0, 2)):
        (tmp_path / f"{name}.json").write_text(json.dumps(_results(f"srp-max:{name}", rmsae, "sim-demo", run, 4)))
    page = build_leaderboards(tmp_path)["sim-demo.md"]
    ranked, partial = page.split("## Partial runs (ranked apart from complete runs)")
    assert "| 1 | `srp-max:a` |" in ranked and "| 2 | `srp-max:b` |" in ranked
    assert "srp-max:c" not in ranked.split("## Runs")[0] and "srp-max:d" not in ranked.split("## Runs")[0]
    assert "| 1 | `srp-max:c` | 1 of 4 episodes (the first 1) | 3.00" in partial
    assert "| 2 | `srp-max:d` | 2 of 4 episodes (the first 2) | 10.00" in partial
    assert "1 of 4 episodes" in partial.split("## Runs")[1]  # its provenance says so too
    rows = list(csv_module.DictReader(build_leaderboards(tmp_path)["sim-demo.csv"].splitlines()))
    assert [(r["rank"], r["tracker"], r["status"]) for r in rows] == [
        ("1", "srp-max:a", "doabench run"), ("2", "srp-max:b", "doabench run"),
        ("P1", "srp-max:c", "partial run (ranked apart)"), ("P2", "srp-max:d", "partial run (ranked apart)")]


@pytest.mark.parametrize("episodes", [1, 2])
def test_a_run_of_one_or_two_episodes_has_no_interval_of_its_own(tmp_path: Path, capsys, episodes: int) -> None:
    """A bootstrap over one or two episodes has (next to) no width: such a file holds no interval
    (null, valid by the schema and by the summary check), ``run`` prints ``n/a``, the leaderboard
    ``[n/a]`` with its legend, also for a file written before, whose interval was ``[x, x]``. An
    edited interval is still caught."""
    jsonschema = pytest.importorskip("jsonschema")
    from conftest import TINY_SCENE
    from doabench.results.schema import summary_problem, validate_results
    from doabench.results.upgrade import upgrade_results
    from doabench.results.writer import format_summary
    from doabench.runner import run_task

    results = run_task("srp-max:4x8", "sim-demo", episodes=episodes, progress=False, keep_frames=False,
                       scene_overrides=TINY_SCENE)
    summary = results["summary"]
    assert summary["rmsae_all_ci95"] is None and summary["rmsae_nonsilent_ci95"] is None
    validate_results(results)
    assert summary_problem(results) is None
    printed = format_summary(results)
    assert "95% CI n/a" in printed and "fewer than 3 episodes with scored frames" in printed
    assert "95% CI [" not in printed
    folder = tmp_path / "results"
    folder.mkdir()
    (folder / "new.json").write_text(json.dumps(results, default=float))
    before = copy.deepcopy(results)  # as an older doabench wrote it: an interval of no width
    before["schema"] = "doabench.results/1"
    before["tracker"]["options"] = {"written": "before"}
    value = summary["rmsae_all"]
    before["summary"]["rmsae_all_ci95"] = [value, value]
    before["summary"]["rmsae_nonsilent_ci95"] = [summary["rmsae_nonsilent"]] * 2
    (folder / "before.json").write_text(json.dumps(before, default=float))
    assert "95% CI n/a" in format_summary(upgrade_results(before))
    files = build_leaderboards(folder)
    page, table = files["sim-demo.md"], files["sim-demo.csv"]
    assert page.count(f"| {value:.2f} [n/a] | {summary['rmsae_nonsilent']:.2f} [n/a] |") == 2  # both files
    assert f"[{value:.2f}, {value:.2f}]" not in page
    assert "**[n/a]**: no 95% interval (fewer than 3 episodes with scored frames" in page
    assert f"{value:.4f},,," in table  # the CSV's interval cells are empty
    edited = copy.deepcopy(results)
    edited["summary"]["rmsae_all_ci95"] = [0.1, 0.2]
    assert "rmsae_all_ci95" in summary_problem(edited)
    with pytest.raises(jsonschema.ValidationError):
        validate_results({**results, "summary": {**summary, "rmsae_all_ci95": "none"}})


def test_an_interval_of_no_width_over_differing_episodes_is_no_interval() -> None:
    """Three episodes of which only one has scored frames resample to one value every time: no
    interval; three differing episodes have one; equal episodes keep their interval of no width."""
    from doabench.metrics import bootstrap_ci_from_sums, defined_interval

    n = np.array([40.0, 60.0, 50.0])
    assert bootstrap_ci_from_sums(np.array([100.0]), np.array([40.0])) is None
    assert bootstrap_ci_from_sums(np.array([100.0, 900.0]), n[:2]) is None
    assert bootstrap_ci_from_sums(np.array([100.0, 0.0, 0.0]), np.array([40.0, 0.0, 0.0])) is None
    low, high = bootstrap_ci_from_sums(np.array([100.0, 900.0, 2500.0]), n)
    assert low < high
    equal = bootstrap_ci_from_sums(9.0 * n, n)
    assert equal == pytest.approx((3.0, 3.0))
    assert defined_interval([1.0, 2.0, 3.0], [5, 5, 5], (2.0, 2.0)) is None  # no width, yet they differ
    assert defined_interval([1.0, 2.0, 3.0], [5, 5, 5], (1.2, 2.8)) == (1.2, 2.8)
    assert defined_interval([1.0, 2.0, 3.0], [5, 5, 5], (float("nan"), 2.0)) is None


@pytest.mark.parametrize("content, reason", [
    ({"schema": 3, "task": {"id": 5}}, '"schema" is 3: not a doabench results file'),
    ({"something": "else"}, 'no "schema" field'),
    ({"schema": "doabench.results/0", "task": {}}, "results schema 'doabench.results/0'; this doabench reads"),
    ({"schema": "doabench.results/1", "task": {"id": 5}}, "task.id is 5 (the results schema wants type string)"),
    ({"schema": "doabench.results/1"}, "no 'task' section"),
])
def test_a_json_file_that_is_not_a_results_file_is_named_and_skipped(results_dir: Path, tmp_path: Path, capsys,
                                                                     content, reason) -> None:
    (results_dir / "stray.json").write_text(json.dumps(content))
    out = tmp_path / "boards"
    capsys.readouterr()
    assert cli(["leaderboard", "--results", str(results_dir), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    stray = [line for line in err.splitlines() if "stray.json" in line]
    assert len(stray) == 1 and "skipped" in stray[0] and reason in stray[0], err
    assert (out / "sim-grid.md").is_file()  # the other files are ranked as before


#: a module that leaves a mark when it is imported
MARKING_MODULE = "import pathlib\npathlib.Path(__file__).with_name('IMPORTED').write_text('module code ran')\n"


def _naming_evilmod(folder: Path) -> dict:
    """A results file whose tracker, given id, weights and task kind all name the module evilmod."""
    results = _results("evilmod:Evil", 20.0)
    results["tracker"].update(given_id="evilmod:Evil", weights_hash="ab" * 32, options={"weights": "evil.safetensors"})
    results["task"]["kind"] = "evilmod"
    return results


def test_reading_results_files_imports_nothing_they_name(tmp_path: Path) -> None:
    """Results files are data, often someone else's: one whose tracker id is ``evilmod:Evil``, read
    where ``evilmod.py`` lies beside it and on the path, is text to ``leaderboard`` and ``compare``;
    the module is never imported, and both commands still work."""
    folder = tmp_path / "shared"
    folder.mkdir()
    (folder / "evilmod.py").write_text(MARKING_MODULE)
    (folder / "sim-grid__evilmod_Evil.json").write_text(json.dumps(_naming_evilmod(folder)))
    (folder / "sim-grid__srp-max_8x16.json").write_text(json.dumps(_results("srp-max:8x16", 30.0)))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(folder), os.environ.get("PYTHONPATH")]))}
    for args in (["leaderboard", "--results", ".", "--out", "boards"],
                 ["compare", "sim-grid__evilmod_Evil.json", "sim-grid__srp-max_8x16.json", "--csv", "c.csv"]):
        proc = subprocess.run([sys.executable, "-m", "doabench", *args], cwd=folder, env=env, capture_output=True,
                              text=True, timeout=600)
        assert proc.returncode == 0, proc.stderr
        assert not (folder / "IMPORTED").exists(), f"doabench {args[0]} imported evilmod"
    assert "`evilmod:Evil (weights=evil.safetensors)`" in (folder / "boards" / "sim-grid.md").read_text()
    assert "evilmod:Evil" in (folder / "c.csv").read_text()


def test_a_name_in_a_results_file_loads_no_plug_in(tmp_path: Path, monkeypatch) -> None:
    """Installed plug-ins are not loaded by a name read from a results file either: a tracker id, a
    task kind and a task prefix declared by a package's entry points stay text to the views."""
    from importlib import metadata

    import doabench.plugins as plugins
    from doabench.reporting.compare import compare
    from doabench.reporting.compare_report import markdown
    from doabench.reporting.pairing import load_run

    (tmp_path / "evilmod.py").write_text(MARKING_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    declared = metadata.entry_points

    def entry_points(**kw):
        found = list(declared(**kw))
        extra = {"doabench.trackers": "evil", "doabench.task_kinds": "evilkind", "doabench.task_prefixes": "evilfile",
                 "doabench.feature_kinds": "evilfeature"}
        if kw.get("group") in extra:
            found.append(metadata.EntryPoint(extra[kw["group"]], "evilmod:Evil", kw["group"]))
        return found

    monkeypatch.setattr(plugins.metadata, "entry_points", entry_points)
    folder = tmp_path / "results"
    folder.mkdir()
    results = _naming_evilmod(folder)
    results["tracker"].update(id="evil:16x32", name="evil")
    results["task"]["kind"] = "evilkind"
    assert "options" not in results["task"]  # as in an old file: its task options are read back through its kind
    results["features"]["kinds"] = ["srp", "evilfeature"]  # an older file's plug-in kind, upgraded as text
    (folder / "sim-grid__evil.json").write_text(json.dumps(results))
    from doabench.results.upgrade import upgrade_results

    upgraded = upgrade_results(copy.deepcopy(results))
    upgraded["tracker"]["id"] = "evil:8x16"
    upgraded["observations"]["kinds"].append({"kind": "evilmap", "grid": "8x16"})  # a current file's plug-in map
    (folder / "sim-grid__evil-current.json").write_text(json.dumps(upgraded))
    other = _results("srp-max:8x16", 30.0)
    (folder / "sim-grid__srp-max_8x16.json").write_text(json.dumps(other))
    page = build_leaderboards(folder)["sim-grid.md"]
    assert "`evil:16x32 (weights=evil.safetensors)`" in page and "--tracker evil:16x32" in page
    assert "evilfeature" in page and "evilmap 8x16" in page
    prefixed = tmp_path / "prefixed"
    prefixed.mkdir()
    (prefixed / "r.json").write_text(json.dumps({**results, "task": {**results["task"], "id": "evilfile:x"}}))
    assert "evilfile_x.md" in build_leaderboards(prefixed)
    runs = [load_run(folder / "sim-grid__evil.json"), load_run(folder / "sim-grid__srp-max_8x16.json")]
    assert "`evil:16x32 (weights=evil.safetensors)`" in markdown([compare(*runs)])
    assert "evilmod" not in sys.modules and not (tmp_path / "IMPORTED").exists()


def test_a_deeply_nested_json_file_is_named_and_skipped(results_dir: Path, tmp_path: Path, capsys) -> None:
    """JSON nested deeper than any results file is never parsed: the leaderboard names it and ranks
    the other files; ``compare`` refuses it in one line."""
    (results_dir / "deep.json").write_text("[" * 100_000 + "]" * 100_000)
    (results_dir / "deep-object.json").write_text('{"a": ' * 5000 + "1" + "}" * 5000)
    (results_dir / "quoted.json").write_text(json.dumps({"text": "[" * 1000}))  # brackets in a string: shallow
    capsys.readouterr()
    assert cli(["leaderboard", "--results", str(results_dir), "--out", str(tmp_path / "boards")]) == 0
    err = capsys.readouterr().err
    for name, depth in (("deep.json", 100_000), ("deep-object.json", 5000)):
        lines = [line for line in err.splitlines() if name in line]
        assert len(lines) == 1 and "skipped" in lines[0] and f"nested {depth} levels deep" in lines[0], err
    assert "quoted.json" in err and 'no "schema" field' in err
    assert (tmp_path / "boards" / "sim-grid.md").is_file()
    assert cli(["compare", str(results_dir / "deep.json"), str(results_dir / "sim-grid__srp-max_8x16.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "nested 100000 levels deep" in err


def test_a_results_folder_entry_that_is_no_regular_file_is_named_and_skipped(results_dir: Path, tmp_path: Path,
                                                                             capsys) -> None:
    """A FIFO or a folder named ``*.json`` is not opened for reading (a FIFO would block): named, skipped."""
    os.mkfifo(results_dir / "pipe.json")
    (results_dir / "folder.json").mkdir()
    capsys.readouterr()
    assert cli(["leaderboard", "--results", str(results_dir), "--out", str(tmp_path / "boards")]) == 0
    err = capsys.readouterr().err
    for name in ("pipe.json", "folder.json"):
        assert any(name in line and "not a regular file" in line for line in err.splitlines()), err


def test_texts_from_results_files_are_escaped_in_markdown_and_csv(results_dir: Path, tmp_path: Path, capsys) -> None:
    """A tracker id holding HTML, a backtick that would close a code span, a Markdown link or a
    spreadsheet formula is shown as text: no tag or link reaches the Markdown the site renders, and
    no CSV cell starts a formula (a leading quote, as OWASP says), in `leaderboard` and `compare`."""
    import csv as csv_module

    hostile = {"html.json": "<img src=x onerror=alert(1)>", "tick.json": "x`<b>bold</b>`[a](javascript:alert(1))",
               "formula.json": '=HYPERLINK("http://evil.example","click")', "at.json": "@SUM(1+1)*cmd|' /C calc'!A0"}
    for name, tracker in hostile.items():
        results = _results(tracker, 20.0)
        results["environment"]["cpu"] = "<script>alert(1)</script>"
        (results_dir / name).write_text(json.dumps(results))
    out = tmp_path / "boards"
    assert cli(["leaderboard", "--results", str(results_dir), "--out", str(out)]) == 0
    compare_csv = tmp_path / "c.csv"
    capsys.readouterr()
    assert cli(["compare", str(results_dir / "html.json"), str(results_dir / "formula.json"),
                str(results_dir / "tick.json"), "--csv", str(compare_csv)]) == 0
    markdown = [p.read_text() for p in out.glob("*.md")] + [capsys.readouterr().out]
    for text in markdown:
        assert "<img" not in text and "<b>" not in text and "<script" not in text and "](javascript" not in text
    page = (out / "sim-grid.md").read_text()
    assert "&lt;img src=x onerror=alert(1)>" in page and "x&#96;&lt;b>bold&lt;/b>&#96;[a]&#40;javascript" in page
    for path in [*out.glob("*.csv"), compare_csv]:
        for row in csv_module.reader(path.read_text().splitlines()):
            assert not any(cell[:1] in ("=", "+", "@", "\t", "\r") for cell in row), (path.name, row)
            assert not any(cell[:1] == "-" and not cell.lstrip("-").replace(".", "", 1).isdigit() for cell in row)
    cells = {cell for row in csv_module.reader((out / "sim-grid.csv").read_text().splitlines()) for cell in row}
    assert "'" + hostile["formula.json"] in cells and "'" + hostile["at.json"] in cells


@pytest.mark.parametrize("claim", [0.5, -5.0])
def test_a_summary_that_disagrees_with_its_episodes_is_refused_and_named(tmp_path: Path, capsys, claim) -> None:
    """A results file edited to claim a better RMSAE than its episode rows give is not published:
    the leaderboard names it and leaves it out, ``compare`` refuses it in one line."""
    folder = tmp_path / "results"
    folder.mkdir()
    for name in ("sim-fan__cross3d_16x32__paper.json", "sim-fan__srp-kalman_32x64.json"):
        (folder / name).write_bytes((ROOT / "results" / name).read_bytes())
    edited = json.loads((folder / "sim-fan__cross3d_16x32__paper.json").read_text())
    edited["summary"]["rmsae_all"] = claim
    (folder / "sim-fan__cross3d_16x32__paper.json").write_text(json.dumps(edited))
    capsys.readouterr()
    assert cli(["leaderboard", "--results", str(folder), "--out", str(tmp_path / "boards")]) == 0
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "sim-fan__cross3d_16x32__paper.json" in line]
    assert len(lines) == 1 and "skipped" in lines[0] and f"summary.rmsae_all is {claim:.4g}" in lines[0], err
    page = (tmp_path / "boards" / "sim-fan.md").read_text()
    assert "cross3d" not in page.split("## ")[0] and f"{claim:.2f} [" not in page and "srp-kalman:32x64" in page
    assert cli(["compare", str(folder / "sim-fan__cross3d_16x32__paper.json"),
                str(folder / "sim-fan__srp-kalman_32x64.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "episode rows pool to" in err


def test_an_interval_that_does_not_hold_its_value_is_refused_and_named(tmp_path: Path, capsys) -> None:
    """A results file whose pooled value is true but whose interval was edited ("12.32 [0.10, 0.20]")
    is named and left out, like an edited value."""
    folder = tmp_path / "results"
    folder.mkdir()
    for name in ("sim-fan__cross3d_16x32__paper.json", "sim-fan__srp-kalman_32x64.json"):
        (folder / name).write_bytes((ROOT / "results" / name).read_bytes())
    edited = json.loads((folder / "sim-fan__cross3d_16x32__paper.json").read_text())
    edited["summary"]["rmsae_all_ci95"] = [0.1, 0.2]
    (folder / "sim-fan__cross3d_16x32__paper.json").write_text(json.dumps(edited))
    capsys.readouterr()
    assert cli(["leaderboard", "--results", str(folder), "--out", str(tmp_path / "boards")]) == 0
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "sim-fan__cross3d_16x32__paper.json" in line]
    assert len(lines) == 1 and "rmsae_all_ci95" in lines[0], err
    assert "[0.10, 0.20]" not in (tmp_path / "boards" / "sim-fan.md").read_text()
