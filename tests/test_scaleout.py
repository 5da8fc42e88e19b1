"""Scale-out: make-dataset and sweep on Ray (a local 2-CPU cluster this module starts and stops),
the one-line error without Ray, and data-parallel training (2 gloo processes = 1 process)."""
from __future__ import annotations

import contextlib
import json
import os
import signal
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

import doabench
from doabench.cli.main import main
from doabench.datasets import make_dataset
from doabench.datasets.generate import parts_dir

TASK, TASK_B = "scaleout-tiny", "scaleout-tiny-b"
TOML = """
id = "{id}"
version = 1
kind = "simulated"
episodes = {n}
base_seed = {seed}
[speech]
corpus = "embedded"
[scene]
duration_s = 1.0
n_points = 8
t60 = [0.2, 0.3]
room_max = [5.0, 5.0, 3.0]
pause_s = [0.1, 0.3]
"""
FEATURES = "srp:4x8,gcc,audio"
RAY_TIMEOUT_S = 120  # a local cluster that hangs fails the test instead of the CI run


@contextlib.contextmanager
def deadline(seconds: int, what: str):
    def fire(*_):
        raise TimeoutError(f"{what} took more than {seconds} s")

    old = signal.signal(signal.SIGALRM, fire)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


@pytest.fixture(scope="module")
def task_dir(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("tasks")
    for task_id, n, seed in ((TASK, 4, 321), (TASK_B, 2, 654)):
        (folder / f"{task_id}.toml").write_text(TOML.format(id=task_id, n=n, seed=seed))
        doabench.register_task(folder / f"{task_id}.toml")
    return folder


@pytest.fixture(scope="module")
def ray_cluster(task_dir):
    """A local Ray instance (2 CPUs, no dashboard) for this module; its workers find the test tasks
    through DOABENCH_TASK_PATH, which they inherit."""
    ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'doabench[ray]')")
    old = os.environ.get("DOABENCH_TASK_PATH")
    os.environ["DOABENCH_TASK_PATH"] = str(task_dir)
    try:
        with deadline(RAY_TIMEOUT_S, "starting Ray"):
            ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
        yield ray
    finally:
        ray.shutdown()
        if old is None:
            os.environ.pop("DOABENCH_TASK_PATH", None)
        else:
            os.environ["DOABENCH_TASK_PATH"] = old


def dataset_bytes(path: Path) -> dict[str, object]:
    """Every dataset of ``episodes/`` with its dtype, shape, values, raw (compressed) chunks and
    attributes, and every group's attributes: what must be the same whatever the engine."""
    out: dict[str, object] = {}

    def visit(name, obj):
        attrs = {k: (v.tobytes() if isinstance(v, np.ndarray) else v) for k, v in obj.attrs.items()}
        if isinstance(obj, h5py.Dataset):
            chunks = []
            if obj.chunks:
                for i in range(obj.id.get_num_chunks()):
                    chunks.append(obj.id.read_direct_chunk(obj.id.get_chunk_info(i).chunk_offset)[1])
            out[name] = (obj.dtype.str, obj.shape, np.asarray(obj[()]).tobytes(), chunks, attrs)
        else:
            out[name] = attrs

    with h5py.File(path, "r") as f:
        f.visititems(visit)
        out["/requested"] = f["requested"][()].tobytes()
        out["/attrs"] = {k: f.attrs[k] for k in ("config", "features", "task_spec", "n_requested")}
    return out


@pytest.fixture(scope="module")
def reference(task_dir, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("ref") / "one.h5"
    make_dataset(TASK, out, features=FEATURES, progress=False)
    return out


# -- make-dataset --engine ray --------------------------------------------------------------------------
def test_ray_dataset_has_the_bytes_of_the_single_process_one(ray_cluster, reference, tmp_path):
    out = tmp_path / "ray.h5"
    seen = []
    with deadline(RAY_TIMEOUT_S, "make-dataset on Ray"):
        result = make_dataset(TASK, out, features=FEATURES, engine="ray", workers=2, progress=seen.append)
    assert sorted(seen) == [0, 1, 2, 3] and result.computed == 4
    assert dataset_bytes(out) == dataset_bytes(reference)
    assert not parts_dir(out).exists()


def test_ray_dataset_resumes_from_the_journal(ray_cluster, reference, tmp_path):
    out = tmp_path / "resumed.h5"

    def stop_after_two(index, seen=[]):  # noqa: B006 - a counter
        seen.append(index)
        if len(seen) == 2:
            raise KeyboardInterrupt

    with deadline(RAY_TIMEOUT_S, "make-dataset on Ray"):
        with pytest.raises(KeyboardInterrupt):
            make_dataset(TASK, out, features=FEATURES, engine="ray", workers=2, progress=stop_after_two)
        assert not out.exists() and len(list(parts_dir(out).glob("*.h5"))) >= 2
        # Resumed through the command line, as a user would (and on the Ray engine again).
        assert main(["make-dataset", "--task", TASK, "--features", FEATURES, "--out", str(out), "--quiet",
                     "--engine", "ray", "--workers", "2"]) == 0
    assert dataset_bytes(out) == dataset_bytes(reference)


def test_without_ray_the_engine_is_a_one_line_error(task_dir, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    out = tmp_path / "x.h5"
    assert main(["make-dataset", "--task", TASK, "--out", str(out), "--engine", "ray"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "doabench[ray]" in err[0] and not parts_dir(out).exists()
    assert main(["sweep", "--trackers", "srp-max:4x8", "--tasks", TASK, "--out", str(tmp_path / "s"),
                 "--engine", "ray"]) == 2
    assert "doabench[ray]" in capsys.readouterr().err


# -- sweep ------------------------------------------------------------------------------------------
SWEEP = ["--trackers", "srp-max:4x8,srp-max:8x16", "--tasks", f"{TASK},{TASK_B}", "--episodes", "2", "--quiet"]


def _summaries(folder: Path) -> dict[str, tuple]:
    import json

    out = {}
    for p in sorted(folder.glob("*.json")):
        r = json.loads(p.read_text())
        out[p.name] = (r["summary"]["rmsae_all"], [e["rmsae_all"] for e in r["episodes"]])
    return out


def test_sweep_runs_every_pair_resumes_and_builds_the_leaderboard(task_dir, tmp_path, capsys):
    out = tmp_path / "results"
    # One run was interrupted after its first episode: its journal is there and is resumed.
    from doabench.runner import run_task
    from doabench.sweep import partial_path_for

    partial = partial_path_for(out, TASK, "srp-max:4x8")
    out.mkdir()

    def stop(i, record):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_task("srp-max:4x8", TASK, episodes=2, partial_path=partial, progress=stop)
    assert partial.exists()
    assert main(["sweep", *SWEEP, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "4 runs (4 run now, 0 already done, 0 failed)" in text
    assert len(_summaries(out)) == 4 and not list(out.glob(".*.partial.jsonl"))
    board = out / "leaderboard"
    assert {p.name for p in board.iterdir()} == {f"{TASK}.md", f"{TASK}.csv", f"{TASK_B}.md", f"{TASK_B}.csv",
                                                 "summary.md"}
    assert "srp-max:8x16" in (board / f"{TASK}.md").read_text()
    # Again: everything is done, nothing is rerun.
    assert main(["sweep", *SWEEP, "--out", str(out)]) == 0
    assert "(0 run now, 4 already done, 0 failed)" in capsys.readouterr().out
    # Each result equals the one `doabench run` gives.
    single = tmp_path / "single"
    assert main(["run", "--tracker", "srp-max:8x16", "--task", TASK_B, "--episodes", "2", "--out", str(single),
                 "--quiet"]) == 0
    name = f"{TASK_B}__srp-max_8x16.json"
    assert _summaries(single)[name] == _summaries(out)[name]


def test_sweep_leaderboard_equals_doabench_leaderboard(task_dir, tmp_path):
    """The sweep writes the same tables `doabench leaderboard` writes for that folder, published
    reference rows kept beside them included."""
    import shutil

    out, board = tmp_path / "results", tmp_path / "board"
    board.mkdir()
    shutil.copy(Path(__file__).resolve().parents[1] / "leaderboards" / "locata-paper-table2.csv", board)
    assert main(["sweep", "--trackers", "srp-max:4x8", "--tasks", TASK, "--episodes", "1", "--quiet",
                 "--out", str(out), "--leaderboard", str(board)]) == 0
    assert "published" in (board / "summary.md").read_text()
    assert main(["leaderboard", "--results", str(out), "--out", str(board), "--check"]) == 0


def test_sweep_redoes_a_run_whose_tracker_weights_changed(task_dir, tmp_path, capsys):
    """A results file written with other weights (e.g. before newly trained weights shipped) is
    not "already done": the sweep runs it again, replacing the file with --overwrite only."""
    import json

    out = tmp_path / "results"
    args = ["sweep", "--trackers", "srp-max:4x8", "--tasks", TASK, "--episodes", "1", "--quiet", "--out", str(out)]
    assert main(args) == 0
    path = out / f"{TASK}__srp-max_4x8.json"
    record = json.loads(path.read_text())
    assert record["tracker"]["weights_hash"] is None  # a classical tracker: no weights
    capsys.readouterr()
    record["tracker"]["weights_hash"] = "0" * 64  # as if written by a learned tracker's older weights
    path.write_text(json.dumps(record))
    # Another configuration's file is not replaced without --overwrite: that run fails at once.
    assert main(args) == 1
    assert "holds a different configuration (weights" in capsys.readouterr().out
    assert json.loads(path.read_text())["tracker"]["weights_hash"] == "0" * 64
    assert main([*args, "--overwrite"]) == 0
    assert "(1 run now, 0 already done, 0 failed)" in capsys.readouterr().out
    assert json.loads(path.read_text())["tracker"]["weights_hash"] is None
