"""Inputs whose simulation would exceed the machine's memory (an absurd T60 or duration, on the
command line, in a task spec or in scene overrides) are refused with one line naming the field and the estimate, exit
status 2, before anything is allocated or written: simulate, run, make-dataset and train."""
from __future__ import annotations

from pathlib import Path

import pytest

import doabench
from doabench.acoustics import budget
from doabench.acoustics.scenes import SceneDistribution
from doabench.cli.main import main

GIB = 2**30
HUGE_T60_TASK = "test-budget-huge-t60"


@pytest.fixture(autouse=True)
def sixteen_gib(monkeypatch):
    """A machine of 16 GiB, whatever this one has: the messages and verdicts do not depend on it."""
    monkeypatch.setattr(budget, "machine_memory", lambda: 16 * GIB)


@pytest.fixture(scope="module")
def huge_t60_task() -> str:
    doabench.register_task({"id": HUGE_T60_TASK, "version": 1, "kind": "simulated", "episodes": 2, "base_seed": 3,
                            "speech": {"corpus": "embedded"}, "scene": {"duration_s": 1.0, "n_points": 8, "t60": 50.0}})
    return HUGE_T60_TASK


def _one_line(capsys) -> str:
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert "\n" not in err and "Traceback" not in err, err
    assert not captured.out.strip(), captured.out
    return err


def test_the_estimate_grows_with_t60_and_duration() -> None:
    paper = budget.costliest_scene(SceneDistribution(), 12)
    assert paper.total < 0.5 * GIB  # the paper's scenes: far below any machine
    assert budget.costliest_scene(SceneDistribution(t60=(50.0, 50.0)), 12).images > 100 * GIB
    long = SceneDistribution(duration_s=1e7, n_points=round(156 * 1e7 / 20))
    assert budget.costliest_scene(long, 12).total > 100 * GIB


def test_every_builtin_simulated_task_fits_in_one_gib(monkeypatch) -> None:
    from doabench.envs.simulated import SimulatedEpisodes

    monkeypatch.setattr(budget, "machine_memory", lambda: GIB)
    for spec in doabench.available_tasks().values():
        if spec.kind == "simulated" and "cells" not in spec.params:
            dist = SimulatedEpisodes._distribution(spec, None)
            budget.check_fits(dist, doabench.get_array(spec.array).n_mics)  # no error


@pytest.mark.parametrize("argv, field", [
    (["--t60", "50", "--snr", "20"], "--t60 50:"),
    (["--duration", "1e9"], "--duration 1e+09:"),
    (["--t60", "1e300"], "--t60 1e+300:"),
])
def test_simulate_refuses_a_scene_beyond_memory(argv, field, tmp_path: Path, capsys) -> None:
    out = tmp_path / "s"
    assert main(["simulate", *argv, "--out", str(out)]) == 2
    err = _one_line(capsys)
    assert field in err and "GiB of memory" in err and "16 GiB of this machine" in err, err
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_run_refuses_a_task_beyond_memory(huge_t60_task: str, tmp_path: Path, capsys) -> None:
    out = tmp_path / "results"
    assert main(["run", "--tracker", "srp-max:4x8", "--task", huge_t60_task, "--out", str(out), "--quiet"]) == 2
    err = _one_line(capsys)
    assert f"task '{huge_t60_task}' scene t60 50 s: simulating a scene needs about" in err, err
    assert not out.exists()


def test_make_dataset_refuses_a_task_beyond_memory(huge_t60_task: str, tmp_path: Path, capsys) -> None:
    assert main(["make-dataset", "--task", huge_t60_task, "--out", str(tmp_path / "d.h5"), "--quiet"]) == 2
    assert f"task '{huge_t60_task}' scene t60 50 s" in _one_line(capsys)
    assert list(tmp_path.iterdir()) == []


def test_simulate_episode_of_a_task_beyond_memory(huge_t60_task: str, tmp_path: Path, capsys) -> None:
    assert main(["simulate", "--task", huge_t60_task, "--episode", "0", "--out", str(tmp_path / "s")]) == 2
    assert f"task '{huge_t60_task}' scene t60 50 s" in _one_line(capsys)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("extra", [[], ["--preset", "cpu", "--build-cache"]])
def test_train_refuses_a_task_beyond_memory(extra: list[str], huge_t60_task: str, tmp_path: Path, capsys) -> None:
    argv = ["train", "--tracker", "cross3d:4x8", "--tracker-opt", "weights=random", "--task", huge_t60_task,
            "--out", str(tmp_path / "run"), "--cache-root", str(tmp_path / "cache"), "--no-compile", "--quiet", *extra]
    assert main(argv) == 2
    assert f"task '{huge_t60_task}' training scene t60 50 s" in _one_line(capsys)
    assert list(tmp_path.iterdir()) == []


def test_scene_overrides_beyond_memory_are_refused_before_the_run() -> None:
    from doabench.errors import ConfigError

    with pytest.raises(ConfigError, match=r"^task 'sim-demo' scene duration_s 1e\+09 s: simulating a scene needs"):
        doabench.run("srp-max:4x8", "sim-demo", episodes=1, progress=False,
                     scene_overrides={"duration_s": 1e9, "n_points": 8})
