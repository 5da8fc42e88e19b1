"""Engines slower than a minute a scene say how long the job takes before it starts: run,
make-dataset, simulate and train, from the scene sizes the memory check uses
(doabench.acoustics.budget.scene_time)."""
from __future__ import annotations

from pathlib import Path

import pytest

import doabench
from doabench.acoustics import budget
from doabench.acoustics.scenes import SceneDistribution
from doabench.cli.main import main
from doabench.envs.registry import get_task_spec
from doabench.envs.simulated import SimulatedEpisodes

from conftest import tiny_task_toml

TASK = "time-tiny-test"
NOTE = "note: the builtin engine is slow here"


@pytest.fixture(scope="module")
def tiny_task(tmp_path_factory) -> str:
    folder = tmp_path_factory.mktemp("tasks")
    (folder / f"{TASK}.toml").write_text(tiny_task_toml(TASK, episodes=2, base_seed=31))
    doabench.register_task(folder / f"{TASK}.toml")
    return TASK


@pytest.fixture
def slow_builtin(monkeypatch):
    """The builtin engine timed as if each image took a second: its 1 s scenes "take" minutes."""
    monkeypatch.setitem(budget._SECONDS_PER_IMAGE, "builtin", 1.0)


def _cell(task: str, t60: float) -> SceneDistribution:
    spec = get_task_spec(task)
    cell = next(c for c in spec.params["cells"] if f"-t60-{t60:g}-" in c)
    return SimulatedEpisodes._distribution(get_task_spec(cell), None)


def test_the_estimate_follows_each_engines_image_count() -> None:
    """pyroomacoustics-full at T60 1.2 s takes minutes a scene (386 s were seen for 3 episodes);
    the builtin engine takes well under a second on the paper's scenes; gpuRIR is not modelled."""
    full = budget.scene_time(_cell("sim-walk-pra-full", 1.2), 12, "pyroomacoustics-full")
    assert full is not None and 120 < full.mean < 900 and full.worst > full.mean
    assert budget.scene_time(_cell("sim-walk-pra-full", 0.3), 12, "pyroomacoustics-full").mean < 30
    torchrir = budget.scene_time(_cell("sim-walk-torchrir", 0.9), 12, "torchrir")
    assert 15 < torchrir.mean < 120  # docs/simulation.md: about 33 s at T60 0.9 s
    assert budget.scene_time(SceneDistribution(), 12, "builtin").mean < 1.0
    assert budget.scene_time(SceneDistribution(), 12, "gpurir") is None
    assert budget.time_note("builtin", [0.2] * 10) is None
    line = budget.time_note("pyroomacoustics-full", [129.0] * 3, 560.0)
    assert line is not None and "\n" not in line
    assert "about 2.1 min an episode, up to 9.3 min for its costliest scene; about 6.5 min for these 3 episodes" in line


def test_a_task_of_a_slow_engine_says_so_for_its_episodes(monkeypatch) -> None:
    """The estimate of a grid's episodes is its cells': sim-grid's T60 1.5 s cell on
    pyroomacoustics-full is slow, its anechoic cell is not; on a GPU nothing is claimed."""
    monkeypatch.setenv("DOABENCH_LIBRISPEECH", "")
    spec = get_task_spec("sim-grid")
    source = SimulatedEpisodes.__new__(SimulatedEpisodes)  # no corpus needed: the cells' distributions only
    source.array, source.device = doabench.get_array("nao"), None
    source.simulator = type("Sim", (), {"name": "pyroomacoustics-full"})()
    source._cells = [(i, SimulatedEpisodes._distribution(get_task_spec(c), None), None)
                     for i, c in enumerate(spec.params["cells"])]
    source._per_cell = spec.episodes // len(source._cells)
    slow = source.time_note([len(source) - 1, len(source) - 2])  # the last cell: T60 1.5 s
    assert slow is not None and "these 2 episodes" in slow
    assert source.time_note([0, 1, 2]) is None  # T60 0: a direct path only
    source.device = "cuda"
    assert source.time_note([len(source) - 1]) is None


def test_run_and_make_dataset_print_the_estimate_before_they_start(tiny_task: str, slow_builtin, tmp_path: Path,
                                                                    capsys) -> None:
    assert main(["run", "--tracker", "srp-max:4x8", "--task", tiny_task, "--episodes", "1",
                 "--out", str(tmp_path / "r"), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert f"{NOTE}: about" in err and "for this episode" in err, err
    assert main(["make-dataset", "--task", tiny_task, "--features", "srp:4x8", "--workers", "2",
                 "--out", str(tmp_path / "d.h5"), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert f"{NOTE}: about" in err and "for these 2 episodes" in err and "with 2 workers" in err, err
    # resumed with nothing left to simulate: no estimate
    assert main(["make-dataset", "--task", tiny_task, "--features", "srp:4x8", "--out", str(tmp_path / "d.h5"),
                 "--quiet"]) == 0
    assert NOTE not in capsys.readouterr().err


def test_simulate_prints_the_estimate_of_its_scene(slow_builtin, tmp_path: Path, capsys) -> None:
    assert main(["simulate", "--t60", "0.3", "--duration", "0.5", "--seed", "2", "--out", str(tmp_path / "s")]) == 0
    err = capsys.readouterr().err
    assert f"{NOTE}: about" in err and "for this scene" in err, err


def test_train_prints_the_estimate_of_an_epoch_and_of_its_caches(tiny_task: str, slow_builtin, tmp_path: Path) -> None:
    from doabench.training.pipeline import ensure_cache, simulation_note
    from doabench.training.recipes import paper_recipe

    spec = get_task_spec(tiny_task)
    recipe = paper_recipe().replace(duration_s=1.0)
    epoch = simulation_note(spec, recipe, "builtin", recipe.trajectories_per_epoch, 3, "an epoch")
    assert epoch is not None and f"an epoch of {recipe.trajectories_per_epoch} trajectories" in epoch
    assert "with 3 workers" in epoch
    logged: list[str] = []
    ensure_cache(tmp_path / "cache", spec, recipe, "val", 1, None, "builtin", logged.append)
    assert any(line.startswith(NOTE) and "for this trajectory" in line for line in logged), logged
