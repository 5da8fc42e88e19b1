"""Partial runs are stratified and kept apart from the ranking, one model is one row (aliases resolve
to a canonical id), a training run given as weights says to export it, and the default outputs of
run, sweep and leaderboard lie under the git-ignored runs/."""
from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from conftest import ROOT, TINY_SCENE
from doabench.cli.main import build_parser, main
from doabench.envs.registry import get_task_spec
from doabench.errors import ConfigError
from doabench.reporting.leaderboard import build_leaderboards
from doabench.envs.selection import select_episodes
from test_leaderboard import _results


# -- which episodes a partial run takes -----------------------------------------------------------------
def test_episodes_on_a_grid_are_spread_over_its_cells():
    grid = get_task_spec("sim-grid")  # 18 cells of 20 episodes, cell after cell
    n = grid.episodes
    per = n // len(grid.params["cells"])
    cell = lambda i: i // per  # noqa: E731
    six, rule = select_episodes(grid, n, 6)
    assert rule == {"rule": "stratified", "episodes": 6, "cells": None}
    assert [cell(i) for i in six] == [1, 4, 7, 10, 13, 16]  # every third cell, not the first six episodes
    both = select_episodes(grid, n, 36)[0]
    assert sorted(cell(i) for i in both) == sorted(list(range(18)) * 2)  # two of every cell
    assert select_episodes(grid, n, 36)[0] == both  # a pure function of N
    assert select_episodes(grid, n, 1000) == (list(range(n)), {"rule": "all", "episodes": None, "cells": None})
    picked, rule = select_episodes(grid, n, 3, ["sim-t60-0.9-snr-30", "sim-t60-0-snr-5"])
    assert rule["cells"] == ["sim-t60-0-snr-5", "sim-t60-0.9-snr-30"] and {cell(i) for i in picked} == {0, 11}
    assert select_episodes(grid, n, None, ["sim-t60-0-snr-5"])[0] == list(range(per))
    # tasks without cells keep the first N
    demo = get_task_spec("sim-demo")
    assert select_episodes(demo, 4, 2) == ([0, 1], {"rule": "first", "episodes": 2, "cells": None})
    with pytest.raises(ConfigError, match="did you mean sim-t60-0-snr-5"):
        select_episodes(grid, n, None, ["sim-t60-0-snr-05"])
    with pytest.raises(ConfigError, match="applies to grid tasks"):
        select_episodes(demo, 4, None, ["sim-t60-0-snr-5"])


def test_a_partial_grid_run_records_its_selection_and_coverage(librispeech_root):
    from doabench.runner import run_task

    results = run_task("srp-max:4x8", "sim-grid", episodes=3, progress=False, keep_frames=False,
                       librispeech=str(librispeech_root), scene_overrides=TINY_SCENE)
    task = results["task"]
    assert task["episodes_run"] == 3 and not task["complete"]
    assert task["selection"] == {"rule": "stratified", "episodes": 3, "cells": None}
    assert task["cells_run"] == 3 and task["cells_total"] == 18
    assert len(results["cells"]) == 3


def test_a_bad_cell_is_a_one_line_error(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", "--tracker", "srp-max:4x8", "--task", "sim-demo", "--cells", "sim-t60-0-snr-5",
                 "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "applies to grid tasks" in err and "\n" not in err and "Traceback" not in err
    assert not out.exists()  # the folder it made is removed again


# -- leaderboards: complete runs ranked, partial ones apart, one row per model, the lag ----------------------
def _write(folder: Path, name: str, results: dict) -> None:
    (folder / name).write_text(json.dumps(results))


def test_only_complete_runs_are_ranked_and_partial_ones_are_listed_with_coverage(tmp_path):
    full = _results("srp-kalman:32x64", 20.0)
    partial = _results("srp-max:8x16", 3.0, episodes_run=1)  # better, on fewer episodes
    partial["task"].update(selection={"rule": "stratified", "episodes": 1, "cells": None}, cells_run=1,
                           cells_total=18)
    _write(tmp_path, "sim-grid__srp-kalman_32x64.json", full)
    _write(tmp_path, "sim-grid__srp-max_8x16.json", partial)
    files = build_leaderboards(tmp_path)
    page = files["sim-grid.md"]
    ranked, rest = page.split("## Partial runs (ranked apart from complete runs)")
    assert "| 1 | `srp-kalman:32x64`" in ranked and "srp-max:8x16" not in ranked.split("## Runs")[0]
    assert "| 1 | `srp-max:8x16` | 1 of 2 episodes, 1 of 18 cells (`--episodes 1` spread over the cells) | 3.00" in rest
    assert "`srp-kalman:32x64`" in files["summary.md"] and "1 (+1 partial)" in files["summary.md"]
    rows = files["sim-grid.csv"].splitlines()
    assert rows[1].startswith("doabench run,1,sim-grid") and rows[2].startswith("partial run (ranked apart),P1,sim-grid")
    assert "--episodes 1" in rest


def test_an_alias_and_its_canonical_id_are_one_row(tmp_path):
    old = _results("cross3d", 12.0)  # written before ids were canonical: the bare alias
    old["tracker"].update(name="cross3d", resolution="16x32", weights_hash="ab" * 32)
    old["environment"]["date"] = "2025-01-01T00:00:00+00:00"
    new = _results("cross3d:16x32", 12.0)
    new["tracker"].update(name="cross3d", resolution="16x32", weights_hash="ab" * 32, resolution_in_id=True)
    other = _results("cross3d:16x32", 14.0)
    other["tracker"].update(name="cross3d", resolution="16x32", weights_hash="cd" * 32, resolution_in_id=True,
                            options={"weights": "v3.safetensors"})
    _write(tmp_path, "sim-grid__cross3d.json", old)
    _write(tmp_path, "sim-grid__cross3d_16x32.json", new)
    _write(tmp_path, "sim-grid__cross3d_16x32__1234abcd.json", other)
    page = build_leaderboards(tmp_path)["sim-grid.md"]
    table = page.split("## Per cell")[0]
    assert table.count("| `cross3d:16x32` |") == 1  # the alias is not a second row
    assert "`cross3d:16x32 (weights=v3.safetensors)`" in table  # other weights: another model, another row
    superseded = page.split("## Superseded files")[1]
    assert "`sim-grid__cross3d.json` (`cross3d`, 2/2 episodes): see R1" in superseded.replace(
        str(tmp_path) + "/", "")


def test_the_lag_column_shows_seconds_and_a_dash_where_no_lag_is_defined(tmp_path):
    moving = _results("srp-kalman:32x64", 12.0)
    moving["summary"]["lag_s"] = 0.35
    static = _results("srp-max:8x16", 20.0)
    static["summary"].update(lag_s=None, lag_note="static source (truth moves below 1 deg/s): no defined lag")
    _write(tmp_path, "sim-grid__srp-kalman_32x64.json", moving)
    _write(tmp_path, "sim-grid__srp-max_8x16.json", static)
    files = build_leaderboards(tmp_path)
    page = files["sim-grid.md"]
    assert "| lag [s] | run |" in page
    assert "| 0.35 | R1 |" in page and "| - | R2 |" in page
    assert "**-**: no defined lag (static source (truth moves below 1 deg/s))" in page
    header = files["sim-grid.csv"].splitlines()[0].split(",")
    row = files["sim-grid.csv"].splitlines()[1].split(",")
    assert row[header.index("lag_s")] == "0.3500"
    # tasks whose results have no lag metric keep their table as it was
    _write(tmp_path, "sim-demo__srp-max_16x32.json", _results("srp-max:16x32", 5.0, "sim-demo", 4, 4))
    assert "lag [s]" not in build_leaderboards(tmp_path)["sim-demo.md"]


# -- one model, one name -----------------------------------------------------------------------------------
def test_aliases_resolve_to_one_canonical_id_and_options(tmp_path, monkeypatch):
    from doabench.trackers.registry import canonical_tracker

    assert canonical_tracker("srp-max") == ("srp-max:16x32", {})
    assert canonical_tracker("srp-max", {"resolution": "8x16"}) == ("srp-max:8x16", {})
    assert canonical_tracker("srp-kalman:32x64", {"q": 0.01, "r": 0.2}) == ("srp-kalman:32x64", {"r": 0.2})
    # the default weights are named (weights=moving-long); the plain paper-recipe file leaves no option
    assert canonical_tracker("cross3d") == ("cross3d:16x32", {"weights": "moving-long"})
    shipped = str(ROOT / "baselines" / "weights" / "cross3d-16x32.safetensors")
    assert canonical_tracker("cross3d", {"weights": shipped, "hold": "auto"}) == ("cross3d:16x32", {})
    v3 = str(ROOT / "baselines" / "weights" / "cross3d-16x32-v3.safetensors")
    assert canonical_tracker("cross3d", {"weights": v3}) == ("cross3d:16x32", {"weights": "paper-v3"})
    assert canonical_tracker("gcc-cnn1d") == ("gcc-cnn1d", {})
    # a class given by its path keeps the path (the id must load it again)
    plugin = tmp_path / "plug"
    plugin.mkdir()
    (plugin / "canon_mod.py").write_text("import doabench\n\n\nclass Mine(doabench.Tracker):\n    name = 'mine'\n")
    monkeypatch.syspath_prepend(str(plugin))
    assert canonical_tracker("canon_mod:Mine") == ("canon_mod:Mine", {})


def test_run_names_the_file_by_the_canonical_id_and_replaces_an_alias_file(tmp_path, capsys):
    out = tmp_path / "r"
    assert main(["run", "--tracker", "srp-max", "--task", "sim-demo", "--episodes", "1", "--out", str(out),
                 "--quiet", "--no-frames"]) == 0
    path = out / "sim-demo__srp-max_16x32.json"
    results = json.loads(path.read_text())
    assert results["tracker"]["id"] == "srp-max:16x32" and results["tracker"]["given_id"] == "srp-max"
    # the same configuration under the alias's name (as written before ids were canonical) is replaced
    legacy = json.loads(path.read_text())
    legacy["schema"] = "doabench.results/1"
    legacy["tracker"]["id"] = "srp-max"
    del legacy["tracker"]["resolution_in_id"], legacy["tracker"]["given_id"]
    (out / "sim-demo__srp-max.json").write_text(json.dumps(legacy))
    (out / "sim-demo__srp-max.csv").write_text("episode\n0\n")
    capsys.readouterr()
    assert main(["run", "--tracker", "srp-max:16x32", "--task", "sim-demo", "--episodes", "1", "--out", str(out),
                 "--quiet", "--no-frames"]) == 0
    assert "replaced" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == ["sim-demo__srp-max_16x32.csv", "sim-demo__srp-max_16x32.json"]


def _checkpoint(folder: Path) -> Path:
    """A file shaped like `doabench train`'s checkpoint: run state metadata, no weights metadata."""
    import torch
    from safetensors.torch import save_file

    folder.mkdir(parents=True)
    path = folder / "checkpoint.safetensors"
    save_file({"model/w": torch.zeros(2)}, str(path),
              metadata={"doabench_state": json.dumps({"tracker": "cross3d:16x32", "epoch": 3})})
    return path


def test_a_training_run_given_as_weights_says_to_export_it(tmp_path, capsys):
    ckpt = _checkpoint(tmp_path / "c16")
    for given in (ckpt.parent, ckpt):
        assert main(["run", "--tracker", "cross3d", "--tracker-opt", f"weights={given}", "--task", "sim-demo",
                     "--out", str(tmp_path / "out"), "--quiet"]) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and "Traceback" not in err
        assert f"doabench train --tracker cross3d:16x32 --out {ckpt.parent} --export c16.safetensors" in err
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["run", "--tracker", "cross3d", "--tracker-opt", f"weights={empty}", "--task", "sim-demo",
                 "--out", str(tmp_path / "out"), "--quiet"]) == 2
    assert "is a folder" in capsys.readouterr().err


# -- defaults that never touch the repository -----------------------------------------------------------------
def test_run_sweep_and_leaderboard_default_to_the_ignored_runs_folder():
    parser = build_parser()
    defaults = {
        "run": parser.parse_args(["run", "--tracker", "srp-max", "--task", "sim-demo"]).out,
        "sweep": parser.parse_args(["sweep", "--trackers", "srp-max", "--tasks", "sim-demo"]).out,
        "leaderboard": parser.parse_args(["leaderboard"]).out,
        "leaderboard --results": parser.parse_args(["leaderboard"]).results[0],  # repeatable: one by default
    }
    assert defaults["leaderboard --results"] == defaults["run"]  # the tables of what run wrote
    for command, folder in defaults.items():
        assert Path(folder).parts[0] == "runs", (command, folder)
    if shutil.which("git") and (ROOT / ".git").exists():
        for folder in defaults.values():
            probe = f"{folder}/x.json"
            ignored = subprocess.run(["git", "check-ignore", probe], cwd=ROOT, capture_output=True, text=True)
            assert ignored.stdout.strip() == probe


def test_a_rerun_that_would_drop_episodes_is_refused_unless_replace(tmp_path, capsys):
    """3 episodes, then a run of 2: refused in one line naming the file and both counts, the file
    untouched, by `run` and `sweep` alike; --replace replaces it; a rerun of the same episodes is
    idempotent, and a run of more episodes extends the file."""
    from doabench.cli.main import main

    out = tmp_path / "r"
    quick = ["--task", "sim-demo", "--tracker", "srp-max:4x8", "--out", str(out), "--quiet", "--no-frames"]
    json_path = out / "sim-demo__srp-max_4x8.json"
    assert main(["run", *quick, "--episodes", "3"]) == 0
    before = json_path.read_bytes()
    capsys.readouterr()
    assert main(["run", *quick, "--episodes", "2"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and str(json_path) in err, err
    assert "with 3 episodes and this run takes 2, without 1 of them: pass --replace" in err
    assert json_path.read_bytes() == before and not list(out.glob(".*"))  # untouched, no journal or lock
    sweep = ["sweep", "--trackers", "srp-max:4x8", "--tasks", "sim-demo", "--quiet", "--no-frames",
             "--out", str(out), "--leaderboard", str(tmp_path / "board")]
    assert main([*sweep, "--episodes", "1"]) == 1
    assert "with 3 episodes and this run takes 1, without 2 of them" in capsys.readouterr().out
    assert json_path.read_bytes() == before
    # the same episodes again: the same scores
    assert main(["run", *quick, "--episodes", "3"]) == 0
    again = json.loads(json_path.read_text())
    assert again["summary"]["rmsae_all"] == json.loads(before)["summary"]["rmsae_all"]
    assert main(["run", *quick, "--episodes", "2", "--replace"]) == 0  # on purpose
    assert json.loads(json_path.read_text())["task"]["episodes_run"] == 2
    assert main([*sweep, "--episodes", "3"]) == 0  # more episodes: extends the file
    assert json.loads(json_path.read_text())["task"]["episodes_run"] == 3
    assert main([*sweep, "--episodes", "1", "--replace"]) == 0
    assert json.loads(json_path.read_text())["task"]["episodes_run"] == 1


def test_run_says_partial_or_full_and_shows_the_committed_full_task_figure(tmp_path, capsys):
    """A 1-episode run says it is partial and not comparable, and prints the committed full run of
    its configuration (results/); a configuration without one prints no such line; the lag is
    defined in one line under its figure."""
    from doabench.cli.main import main
    from doabench.results.writer import LAG_DEFINITION

    committed = json.loads((ROOT / "results" / "sim-demo__srp-max_16x32.json").read_text())
    quick = ["--task", "sim-demo", "--episodes", "1", "--quiet", "--no-frames", "--out", str(tmp_path)]
    assert main(["run", "--tracker", "srp-max", *quick]) == 0
    out = capsys.readouterr().out
    assert ("partial run: 1 of 4 episodes of sim-demo v2, ranked apart from full runs on its leaderboard: its figures "
            "are not comparable with a full-task figure") in out
    s = committed["summary"]
    assert (f"committed full-task run of this configuration ({ROOT / 'results' / 'sim-demo__srp-max_16x32.json'}"
            if Path.cwd().resolve() != ROOT.resolve() else
            "committed full-task run of this configuration (results/sim-demo__srp-max_16x32.json") in out
    assert (f"4 episodes): RMSAE all frames {s['rmsae_all']:.2f} [{s['rmsae_all_ci95'][0]:.2f}, "
            f"{s['rmsae_all_ci95'][1]:.2f}] deg") in out
    lag = out.splitlines().index(LAG_DEFINITION)
    assert out.splitlines()[lag - 1].startswith("tracking lag [s]")
    assert main(["run", "--tracker", "srp-max:4x8", *quick]) == 0  # no committed run of this configuration
    out = capsys.readouterr().out
    assert "partial run: 1 of 4 episodes" in out and "committed full-task run" not in out


def test_a_partial_rerun_never_replaces_a_complete_run(tmp_path, capsys):
    from doabench.cli.main import main

    out = tmp_path / "r"
    quick = ["--task", "sim-demo", "--tracker", "srp-max:4x8", "--out", str(out), "--quiet", "--no-frames"]
    assert main(["run", *quick]) == 0
    json_path = out / "sim-demo__srp-max_4x8.json"
    before = json_path.read_bytes()
    assert main(["run", *quick, "--episodes", "1"]) == 2
    assert "holds a complete run of this configuration with 4 episodes and this run takes 1" in capsys.readouterr().err
    assert json_path.read_bytes() == before
    assert main(["run", *quick, "--episodes", "1", "--overwrite"]) == 0  # on purpose
