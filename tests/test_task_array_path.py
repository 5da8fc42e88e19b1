"""A task spec's relative ``array`` file is read from the spec file's folder, whatever the working
directory; built-in names and absolute paths stay as written."""
from __future__ import annotations

import uuid
from pathlib import Path

import pytest

from doabench.arrays import get_array
from doabench.envs.registry import get_task_spec, register_task
from doabench.envs.spec import load_spec_file, resolve_array_path
from doabench.errors import DoabenchError

RING6 = """name: ring-6
positions:
  - [0.05, 0.0, 0.0]
  - [0.025, 0.0433, 0.0]
  - [-0.025, 0.0433, 0.0]
  - [-0.05, 0.0, 0.0]
  - [-0.025, -0.0433, 0.0]
  - [0.025, -0.0433, 0.0]
"""


def _task_folder(tmp_path: Path, array: str, task_id: str) -> Path:
    folder = tmp_path / "my-tasks"
    (folder / "arrays").mkdir(parents=True)
    (folder / "ring6.yaml").write_text(RING6)
    (folder / "arrays" / "ring6.yaml").write_text(RING6)
    (folder / f"{task_id}.toml").write_text(f"""id = "{task_id}"
version = 0
kind = "simulated"
array = "{array}"
episodes = 1
base_seed = 1

[speech]
corpus = "embedded"

[scene]
duration_s = 1.5
n_points = 12
""")
    return folder


@pytest.mark.parametrize("array", ["ring6.yaml", "arrays/ring6.yaml", "./ring6.yaml"])
def test_relative_array_file_loads_from_another_working_directory(tmp_path: Path, monkeypatch, array: str) -> None:
    task_id = f"ring-task-{uuid.uuid4().hex[:8]}"
    folder = _task_folder(tmp_path, array, task_id)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # no ring6.yaml here: the working directory must not matter
    (spec,) = load_spec_file(folder / f"{task_id}.toml")
    assert Path(spec.array).is_absolute() and Path(spec.array).is_file()
    assert get_array(spec.array).n_mics == 6
    # Registered through a relative spec path too, and run as an environment.
    monkeypatch.chdir(tmp_path)
    register_task(Path("my-tasks") / f"{task_id}.toml")
    monkeypatch.chdir(elsewhere)
    from doabench.envs.env import DoaEnv

    env = DoaEnv(get_task_spec(task_id), features=("srp",), resolution=(4, 8))
    assert env.array.n_mics == 6 and env.array.planar


def test_names_and_absolute_paths_are_kept(tmp_path: Path) -> None:
    assert resolve_array_path("nao", tmp_path) == "nao"
    assert resolve_array_path("benchmark2", tmp_path) == "benchmark2"
    absolute = str(tmp_path / "x.json")
    assert resolve_array_path(absolute, "/somewhere/else") == absolute
    assert resolve_array_path("x.json", tmp_path) == str((tmp_path / "x.json").resolve())


def test_missing_relative_array_file_names_the_resolved_path(tmp_path: Path, monkeypatch) -> None:
    task_id = f"ring-task-{uuid.uuid4().hex[:8]}"
    folder = _task_folder(tmp_path, "missing.yaml", task_id)
    monkeypatch.chdir(tmp_path)
    (spec,) = load_spec_file(folder / f"{task_id}.toml")
    with pytest.raises(DoabenchError) as exc:
        get_array(spec.array)
    assert str(folder / "missing.yaml") in str(exc.value)
