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


@pytest.mark.parametrize("backend, t60, refused", [
    ("pyroomacoustics-full", "5", "pyroomacoustics-full's image sources to reflection order 595"),
    ("pyroomacoustics", "5", "pyroomacoustics's image sources"),
    ("torchrir", "400", "the torchrir engine"),
])
def test_each_engine_has_its_own_budget(backend: str, t60: str, refused: str, tmp_path: Path, capsys) -> None:
    """pyroomacoustics-full at T60 5 s passed the builtin engine's check (about 1 GiB) and died in
    ``std::bad_alloc``: its images to order 595 (281 million) are counted; so are pyroomacoustics'
    images of 8 sources a room and torchrir's float32 responses."""
    pytest.importorskip("torchrir" if backend == "torchrir" else "pyroomacoustics")
    out = tmp_path / "s"
    assert main(["simulate", "--backend", backend, "--t60", t60, "--out", str(out)]) == 2
    err = _one_line(capsys)
    # the field driving the cost: the T60 for the image sources, the trajectory for torchrir's responses
    field = "scene n_points 156:" if backend == "torchrir" else f"--t60 {t60}:"
    assert f"{field} simulating a scene needs about" in err and refused in err, err
    assert "16 GiB of this machine" in err and list(tmp_path.iterdir()) == []
    assert budget.costliest_scene(SceneDistribution(t60=(5.0, 5.0)), 12).total < 2 * GIB  # the builtin's: fits


def test_the_engines_budgets_follow_their_image_counts() -> None:
    """The paper's scenes fit every engine in 4 GiB; pyroomacoustics-full's order follows
    pyroomacoustics' inverse_sabine rule at Tmax, and its images the octahedron of that order."""
    pytest.importorskip("pyroomacoustics")
    import pyroomacoustics as pra

    from doabench.acoustics.room import max_time

    for backend in ("builtin", "pyroomacoustics", "pyroomacoustics-full", "torchrir"):
        assert budget.costliest_scene(SceneDistribution(), 12, backend).total < 4 * GIB, backend
    for dims, t60 in (((3.0, 3.0, 2.5), 0.9), ((6.0, 5.0, 3.0), 1.3), ((3.0, 4.0, 2.5), 5.0)):
        assert budget.pra_full_order(dims, t60) == pra.inverse_sabine(max_time(t60), list(dims), c=343.0)[1]
    assert [budget.octahedral_images(n) for n in (0, 1, 2)] == [1, 7, 25]


def test_train_checks_the_memory_of_its_own_engine(tmp_path: Path, capsys) -> None:
    """`train --backend pyroomacoustics-full` is checked against that engine's budget (its images to
    the reflection order of T60 5 s), not the builtin engine's, before anything is written."""
    pytest.importorskip("pyroomacoustics")
    doabench.register_task({"id": "x-train-t60-5", "version": 1, "kind": "simulated", "episodes": 2, "base_seed": 3,
                            "speech": {"corpus": "embedded"}, "scene": {"duration_s": 1.0, "n_points": 8, "t60": 5.0}})
    argv = ["train", "--tracker", "cross3d:4x8", "--tracker-opt", "weights=random", "--task", "x-train-t60-5",
            "--out", str(tmp_path / "run"), "--cache-root", str(tmp_path / "cache"), "--no-compile", "--quiet"]
    assert main([*argv, "--backend", "pyroomacoustics-full"]) == 2
    assert "pyroomacoustics-full's image sources" in _one_line(capsys)
    assert list(tmp_path.iterdir()) == []
