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
from conftest import tiny_task_toml
import torch

import doabench
from doabench.cli.main import main
from doabench.datasets import make_dataset
from doabench.datasets.generate import parts_dir

TASK, TASK_B = "scaleout-tiny", "scaleout-tiny-b"
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
        (folder / f"{task_id}.toml").write_text(tiny_task_toml(task_id, n, seed, extra_scene="pause_s = [0.1, 0.3]\n"))
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
    from doabench.runner import RunSpec, run_task

    partial = RunSpec.build("srp-max:4x8", TASK)[0].journal_path(out)  # where sweep and run keep it
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


def test_sweep_redoes_a_run_of_another_tracker_version(task_dir, tmp_path, capsys):
    """A results file from an older version of the tracker (e.g. before the learned trackers held
    in silences) is redone; the configuration is the same, so no --overwrite is needed."""
    import json

    out = tmp_path / "results"
    args = ["sweep", "--trackers", "srp-max:4x8", "--tasks", TASK, "--episodes", "1", "--quiet", "--out", str(out)]
    assert main(args) == 0
    path = out / f"{TASK}__srp-max_4x8.json"
    record = json.loads(path.read_text())
    current = record["tracker"]["version"]
    record["tracker"]["version"] = "0"
    path.write_text(json.dumps(record))
    capsys.readouterr()
    assert main(args) == 0
    assert "(1 run now, 0 already done, 0 failed)" in capsys.readouterr().out
    assert json.loads(path.read_text())["tracker"]["version"] == current
    assert main(args) == 0
    assert "(0 run now, 1 already done, 0 failed)" in capsys.readouterr().out


def test_sweep_reports_a_failing_run_and_goes_on(task_dir, tmp_path, monkeypatch, capsys):
    assert main(["sweep", "--trackers", "srp-max:4x8x9", "--tasks", TASK_B, "--out", str(tmp_path)]) == 2
    assert "4x8x9" in capsys.readouterr().err  # a bad tracker id: one line, before any run
    plugin = tmp_path / "plugins"
    plugin.mkdir()
    (plugin / "raising_sweep_mod.py").write_text(
        "import doabench\n\n\nclass Mid(doabench.Tracker):\n    name = 'mid'\n\n"
        "    def step(self, observation):\n        raise ZeroDivisionError('mid-episode')\n")
    monkeypatch.syspath_prepend(str(plugin))
    out = tmp_path / "out"
    code = main(["sweep", "--trackers", "raising_sweep_mod:Mid,srp-max:4x8", "--tasks", TASK_B, "--episodes", "1",
                 "--out", str(out), "--quiet"])
    text = capsys.readouterr().out
    assert code == 1 and "1 failed" in text and "mid-episode" in text
    assert [p.name for p in out.glob("*.json")] == [f"{TASK_B}__srp-max_4x8.json"]
    assert (out / "leaderboard" / f"{TASK_B}.md").is_file()


def test_sweep_on_ray_gives_the_local_results(ray_cluster, tmp_path, capsys):
    local, remote = tmp_path / "local", tmp_path / "ray"
    assert main(["sweep", *SWEEP, "--out", str(local)]) == 0
    with deadline(RAY_TIMEOUT_S, "sweep on Ray"):
        assert main(["sweep", *SWEEP, "--out", str(remote), "--engine", "ray"]) == 0
    assert _summaries(remote) == _summaries(local)
    assert (remote / "leaderboard" / "summary.md").is_file()


# -- data-parallel training (torchrun's environment, gloo on CPU) ----------------------------------------
def test_rank_batches_split_every_global_batch():
    from doabench.training.distributed import rank_batches

    per_rank = [rank_batches(7, 4, r, 3) for r in range(3)]
    for b, size in enumerate((4, 3)):
        got = sorted(i for batches, weights in per_rank for i, w in zip(batches[b], [weights[b]] * 9) if w > 0)
        assert got == list(range(4 * b, 4 * b + size))
        assert sum(weights[b] for _, weights in per_rank) == pytest.approx(1.0)
    batches, weights = rank_batches(5, 4, 1, 2)  # the last batch has 1 item: rank 1 gets a stand-in
    assert batches == [[2, 3], [4]] and weights == [0.5, 0.0]


DDP_RECIPE = dict(epochs=2, trajectories_per_epoch=5)  # batches 2,2,1 then 4,1: uneven splits included


def _no_plot(*args, **kwargs) -> None:  # loss.png costs a matplotlib import per process; not tested here
    return None


def _ddp_rank(rank: int, world: int, ports: list, out: str, caches: tuple, runs: list) -> None:
    """One rank, as torchrun starts it (its environment variables), training the tiny tracker: one
    invocation per ``(max_epochs, resume)`` of ``runs`` (a new process group and Trainer each,
    the second reading the checkpoint the first left, as a run restarted with --resume does)."""
    import torch

    from doabench.training.distributed import run_distributed
    from doabench.training.trainer import TrainOptions
    from test_training import energy_features, tiny_recipe, tiny_tracker, use_energy_kind

    import doabench.training.trainer as trainer_module

    use_energy_kind()

    trainer_module.plot_history = _no_plot
    os.environ.update(RANK=str(rank), WORLD_SIZE=str(world), LOCAL_RANK=str(rank), MASTER_ADDR="127.0.0.1")
    torch.set_num_threads(1)
    for port, (max_epochs, resume) in zip(ports, runs):
        os.environ["MASTER_PORT"] = str(port)  # a fresh rendezvous per invocation, as torchrun gives
        opts = TrainOptions(tracker="tiny", out=Path(out), recipe=tiny_recipe(**DDP_RECIPE), progress=False,
                            workers=0, precision="fp32", max_epochs=max_epochs, resume=resume)
        run_distributed(opts, log=lambda m: None, timeout_s=120, tracker=tiny_tracker(), feature_fn=energy_features,
                        train_cache=caches[0], val_cache=caches[1])


def _free_ports(n: int) -> list[int]:
    import socket

    sockets = [socket.socket() for _ in range(n)]
    try:
        for s in sockets:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in sockets]
    finally:
        for s in sockets:
            s.close()


def _launch(world: int, out: str, caches: tuple, runs: list) -> None:
    import torch.multiprocessing as mp

    args = (world, _free_ports(len(runs)), out, caches, runs)
    ctx = mp.start_processes(_ddp_rank, args=args, nprocs=world, join=False, start_method="spawn")
    try:
        with deadline(120, f"{world}-process training"):
            while not ctx.join(timeout=1):
                pass
    finally:
        for p in ctx.processes:
            if p.is_alive():
                p.kill()


def test_two_processes_train_the_weights_of_one_and_resume(tmp_path, monkeypatch):
    from doabench.training import checkpoint as ckpt
    from doabench.training.trainer import TrainOptions, Trainer
    from test_training import energy_features, make_cache, tiny_recipe, tiny_tracker, use_energy_kind

    use_energy_kind(monkeypatch)
    monkeypatch.setattr("doabench.training.trainer.plot_history", _no_plot)
    caches = (make_cache(tmp_path / "train", 6, 1), make_cache(tmp_path / "val", 2, 2))
    one = tmp_path / "one"
    opts = TrainOptions(tracker="tiny", out=one, recipe=tiny_recipe(**DDP_RECIPE), progress=False, workers=0,
                        precision="fp32")
    Trainer(opts, tracker=tiny_tracker(), feature_fn=energy_features, train_cache=caches[0], val_cache=caches[1],
            log=lambda m: None).run()
    two = tmp_path / "two"
    _launch(2, str(two), caches, [(1, False), (None, True)])  # 1 epoch, stopped, then resumed for the second
    a, b = ckpt.load_checkpoint(one / ckpt.LATEST), ckpt.load_checkpoint(two / ckpt.LATEST)
    assert b["epoch"] == 2 and set(a["model"]) == set(b["model"])
    init = tiny_tracker().network.state_dict()
    for name in a["model"]:
        torch.testing.assert_close(b["model"][name], a["model"][name], rtol=1e-5, atol=1e-6)
        assert not torch.allclose(a["model"][name], init[name], atol=1e-4)  # the steps did move the weights
    for ha, hb in zip(a["history"], b["history"], strict=True):
        assert hb["train_loss"] == pytest.approx(ha["train_loss"], rel=1e-5)
        assert hb["val_rmsae_all"] == pytest.approx(ha["val_rmsae_all"], rel=1e-4)
        assert hb["trajectories_seen"] == ha["trajectories_seen"]
    assert len((two / "log.csv").read_text().splitlines()) == 3  # header + 2 epochs, written once
    assert json.loads((two / "distributed.json").read_text())["world_size"] == 2


def test_sweep_with_options_finds_its_own_finished_runs(task_dir, tmp_path, capsys):
    """Runs with options or exact delays are named by a configuration hash; a second sweep with
    the same settings must find them (and rerun nothing)."""
    out = tmp_path / "results"
    args = ["sweep", "--trackers", "srp-max:4x8", "--tasks", TASK, "--episodes", "1", "--delays", "exact",
            "--quiet", "--out", str(out)]
    assert main(args) == 0
    names = [p.name for p in out.glob("*.json")]
    assert len(names) == 1 and names[0].startswith(f"{TASK}__srp-max_4x8__")
    capsys.readouterr()
    assert main(args) == 0
    assert "(0 run now, 1 already done, 0 failed)" in capsys.readouterr().out
