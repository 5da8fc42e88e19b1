"""Ctrl-C and SIGTERM, and two processes on one output.

A command stopped by SIGINT or SIGTERM prints one line (what was kept, the command that resumes),
no traceback, leaves nothing half-written, and the resumed result equals an uninterrupted one:
each case runs the real command in a subprocess and signals it mid-work. Two processes writing
the same output: one proceeds, the other gets one line naming the first one's pid; a lock left
by a killed process is taken over."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from doabench.cli.main import main

from conftest import ROOT, tiny_task_toml

# A causal SRP tracker slow enough (about a second per sim-demo episode) to be caught mid-run.
# With $DOABENCH_TEST_HOLD naming a file, it also waits before its second episode while that file
# exists: a test holds the run there, so that on any machine it is still running when checked.
SLOW_TRACKER = '''
import os, time
from pathlib import Path
from doabench.trackers.srp import SrpMaxTracker


class SlowMax(SrpMaxTracker):
    name = "slow-max"
    episodes = 0

    def reset(self, *args, **kwargs):
        hold = os.environ.get("DOABENCH_TEST_HOLD")
        while hold and SlowMax.episodes >= 1 and Path(hold).exists():
            time.sleep(0.02)
        SlowMax.episodes += 1
        return super().reset(*args, **kwargs)

    def step(self, observation):
        time.sleep(0.02)
        return super().step(observation)
'''
TRACKER = "slowtracker:SlowMax:4x8"

DATASET_TASK = tiny_task_toml("int-tiny-test", episodes=6, base_seed=41)


@pytest.fixture(scope="module")
def plugin(tmp_path_factory) -> dict[str, str]:
    """The environment of the subprocesses: the slow tracker's module and a tiny dataset task."""
    folder = tmp_path_factory.mktemp("plugin")
    (folder / "slowtracker.py").write_text(SLOW_TRACKER)
    (folder / "tasks").mkdir()
    (folder / "tasks" / "int-tiny-test.toml").write_text(DATASET_TASK)
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(folder), str(ROOT), str(ROOT / "tests")]),
                DOABENCH_TASK_PATH=str(folder / "tasks"), PYTHONUNBUFFERED="1")


def doabench(*args: str) -> list[str]:
    return [sys.executable, "-m", "doabench", *args]


def start(cmd: list[str], env: dict, cwd: Path) -> subprocess.Popen:
    return subprocess.Popen(cmd, env=env, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def wait_for(proc: subprocess.Popen, ready, timeout: float = 300) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if ready():
            return
        assert proc.poll() is None, f"the command ended before it could be stopped: {proc.communicate()}"
        time.sleep(0.02)
    proc.kill()
    raise AssertionError("the command never reached the point to stop it at")


def stop(proc: subprocess.Popen, sig: int) -> tuple[int, str]:
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=300)
    return proc.returncode, err


def one_line(err: str) -> str:
    """The stop message: the last line of stderr (a progress bar may come before it), the only line
    that is not a progress bar, and no traceback."""
    assert "Traceback" not in err, err
    lines = [ln for ln in err.replace("\r", "\n").splitlines() if ln.strip() and "%|" not in ln]
    assert len(lines) == 1, err
    return lines[0]


def journal_records(folder: Path) -> int:
    journals = list(folder.glob(".*.partial.jsonl"))
    return max((len(p.read_text().splitlines()) - 1 for p in journals), default=0)


def no_debris(folder: Path) -> None:
    left = [p.name for p in folder.rglob("*") if p.name.endswith((".tmp", ".partial", ".lock"))
            or (p.name.startswith(".") and ".partial.jsonl" not in p.name and p.name != "lock")]
    assert not left, left


def scores(results: dict) -> tuple:
    rows = [{k: v for k, v in row.items() if k != "tracker_s"} for row in results["episodes"]]
    return results["summary"], rows, results["frames"]


RUN = ["run", "--tracker", TRACKER, "--task", "sim-demo", "--quiet"]


@pytest.fixture(scope="module")
def straight_run(plugin, tmp_path_factory) -> dict:
    """The uninterrupted run every resumed one must equal."""
    out = tmp_path_factory.mktemp("straight")
    done = subprocess.run(doabench(*RUN, "--out", str(out)), env=plugin, cwd=out, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr
    return json.loads(next(out.glob("*.json")).read_text())


@pytest.mark.parametrize("sig,name,code", [(signal.SIGTERM, "SIGTERM", 143), (signal.SIGINT, "Ctrl-C", 130)])
def test_run_stopped_by_a_signal_says_what_it_kept_and_resumes_to_the_same_result(sig, name, code, plugin,
                                                                                  straight_run, tmp_path):
    out = tmp_path / "r"
    cmd = doabench(*RUN, "--out", str(out))
    proc = start(cmd, plugin, tmp_path)
    wait_for(proc, lambda: out.is_dir() and journal_records(out) >= 1)
    rc, err = stop(proc, sig)
    line = one_line(err)
    assert rc == code, err
    assert line.startswith(f"doabench run: stopped by {name}; ") and "kept in" in line
    assert "resume with the same command: doabench run --tracker" in line
    assert not list(out.glob("*.json")) and not list(out.glob("*.csv"))  # nothing half-written
    for text in next(out.glob(".*.partial.jsonl")).read_text().splitlines():
        json.loads(text)
    no_debris(out)
    done = subprocess.run(cmd, env=plugin, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert scores(json.loads(next(out.glob("*.json")).read_text())) == scores(straight_run)
    assert not list(out.glob(".*"))  # journal and lock gone


def test_sweep_stopped_by_sigterm_resumes_to_the_runs_results(plugin, tmp_path):
    straight = tmp_path / "straight"
    assert main(["run", "--tracker", "srp-max:8x16", "--task", "sim-demo", "--out", str(straight), "--quiet"]) == 0
    out = tmp_path / "s"
    cmd = doabench("sweep", "--trackers", "srp-max:4x8,srp-max:8x16", "--tasks", "sim-demo", "--out", str(out),
                   "--quiet")
    proc = start(cmd, plugin, tmp_path)
    # stopped inside the second run, after its first episode
    wait_for(proc, lambda: out.is_dir() and any(p for p in out.glob("*.json") if not p.name.startswith("."))
             and journal_records(out) >= 1)
    rc, err = stop(proc, signal.SIGTERM)
    line = one_line(err)
    assert rc == 143 and line.startswith("doabench sweep: stopped by SIGTERM; kept 1 results file and ")
    assert "resume with the same command" in line and "doabench sweep --trackers" in line
    done = subprocess.run(cmd, env=plugin, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert "already done" in done.stdout
    name = next(straight.glob("*.json")).name
    assert scores(json.loads((out / name).read_text())) == scores(json.loads((straight / name).read_text()))
    assert (out / "leaderboard" / "summary.md").is_file()


def test_make_dataset_stopped_by_sigterm_resumes_to_the_same_file(plugin, tmp_path):
    from doabench.datasets import DatasetFile
    from doabench.datasets.generate import parts_dir
    from doabench.datasets.layout import read_episode

    def episodes(path: Path) -> list:
        with DatasetFile(path) as f:
            return [read_episode(f.file["episodes"][f"{i:06d}"]) for i in f.indices]

    straight = tmp_path / "straight.h5"
    cmd = doabench("make-dataset", "--task", "int-tiny-test", "--features", "srp:4x8", "--quiet")
    assert subprocess.run([*cmd, "--out", str(straight)], env=plugin, capture_output=True, timeout=600).returncode == 0
    out = tmp_path / "d.h5"
    proc = start([*cmd, "--out", str(out)], plugin, tmp_path)
    wait_for(proc, lambda: parts_dir(out).is_dir() and any(parts_dir(out).glob("0*.h5")))
    rc, err = stop(proc, signal.SIGTERM)
    line = one_line(err)
    assert rc == 143 and line.startswith("doabench make-dataset: stopped by SIGTERM; ")
    assert f"kept in {parts_dir(out)}" in line and "resume with the same command: doabench make-dataset" in line
    assert not out.exists() and not list(parts_dir(out).glob(".*.tmp")) and not (parts_dir(out) / "lock").exists()
    done = subprocess.run([*cmd, "--out", str(out)], env=plugin, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert "from an earlier run" in done.stdout and not parts_dir(out).exists()
    for a, b in zip(episodes(straight), episodes(out), strict=True):
        assert a.arrays.keys() == b.arrays.keys() and all(np.array_equal(a.arrays[k], b.arrays[k]) for k in a.arrays)


def test_track_stopped_by_sigterm_writes_nothing(plugin, tmp_path):
    import soundfile as sf

    rec = tmp_path / "long.wav"
    sf.write(str(rec), np.random.default_rng(1).standard_normal((16000 * 60, 12)).astype(np.float32) * 0.1, 16000)
    out = tmp_path / "doa.csv"
    proc = start(doabench("track", str(rec), "--tracker", TRACKER, "--out", str(out)), plugin, tmp_path)
    time.sleep(4)  # the minute of audio takes the slow tracker about 6 s
    rc, err = stop(proc, signal.SIGTERM)
    line = one_line(err)
    assert rc == 143 and "nothing was written" in line and "doabench track" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["long.wav"]


# -- train ---------------------------------------------------------------------------------------------
# `doabench train` itself (parser, main, the signal handling), with the tiny tracker, features and
# caches of tests/test_training.py injected into its Trainer, slowed down so an epoch can be stopped.
TRAIN_SCRIPT = '''
import os, sys, time
from pathlib import Path
import doabench
import doabench.training.trainer as trainer_module
from test_training import TinyTracker, energy_features, make_cache, use_energy_kind

use_energy_kind()
caches = Path(sys.argv[1])
if not caches.exists():
    make_cache(caches / "train", 16, 1)
    make_cache(caches / "val", 2, 2)
doabench.register_tracker("tiny-trainable")(TinyTracker)


class SlowTrainer(trainer_module.Trainer):
    def __init__(self, options, log=print):
        super().__init__(options, feature_fn=energy_features, train_cache=caches / "train",
                         val_cache=caches / "val", log=log)

    def train_step(self, batch):
        time.sleep(1.0)
        hold = os.environ.get("DOABENCH_TEST_HOLD")  # held after the first checkpoint while the file exists
        while hold and Path(hold).exists() and (self.out / "checkpoint.safetensors").exists():
            time.sleep(0.02)
        return super().train_step(batch)


trainer_module.Trainer = SlowTrainer
from doabench.cli.main import main
sys.exit(main(sys.argv[2:]))
'''


def train_cmd(script: Path, caches: Path, out: Path, *extra: str) -> list[str]:
    return [sys.executable, str(script), str(caches), "train", "--tracker", "tiny-trainable", "--preset", "cpu",
            "--epochs", "3", "--epoch-size", "16", "--cache-size", "16", "--val-trajectories", "2", "--workers", "0",
            "--precision", "fp32", "--no-compile", "--quiet", "--out", str(out), *extra]


def test_train_stopped_mid_epoch_keeps_the_last_epoch_and_resumes_exactly(plugin, tmp_path):
    from doabench.training.checkpoint import LATEST, load_checkpoint

    script = tmp_path / "train.py"
    script.write_text(TRAIN_SCRIPT)
    caches = tmp_path / "caches"
    straight = subprocess.run(train_cmd(script, caches, tmp_path / "straight"), env=plugin, capture_output=True,
                              text=True, timeout=900)
    assert straight.returncode == 0, straight.stderr
    out = tmp_path / "run"
    proc = start(train_cmd(script, caches, out), plugin, tmp_path)
    # epoch 1 is checkpointed (log and plot come after the checkpoint), then a moment into epoch 2
    wait_for(proc, lambda: (out / "loss.png").is_file(), timeout=600)
    time.sleep(0.5)
    rc, err = stop(proc, signal.SIGTERM)
    line = one_line(err)
    assert rc == 143, err
    assert line.startswith(f"doabench train: stopped by SIGTERM; the checkpoint after epoch 1 is kept in {out}; "
                           "epoch 2 was stopped after ")
    assert "which a resume does again from the epoch's start" in line and line.endswith(" --resume")
    assert load_checkpoint(out / LATEST)["epoch"] == 1
    assert not list(out.glob(".*"))  # no temporary checkpoint, no lock left
    resumed = subprocess.run(train_cmd(script, caches, out, "--resume"), env=plugin, capture_output=True, text=True,
                             timeout=900)
    assert resumed.returncode == 0, resumed.stderr
    a, b = load_checkpoint(tmp_path / "straight" / LATEST), load_checkpoint(out / LATEST)
    assert a["epoch"] == b["epoch"] == 3
    for k, v in a["model"].items():
        assert np.array_equal(v.numpy(), b["model"][k].numpy()), k
    assert [h["val_loss"] for h in a["history"]] == [h["val_loss"] for h in b["history"]]


def test_two_trains_on_one_run_folder(plugin, tmp_path):
    from doabench.training.checkpoint import LATEST

    script = tmp_path / "train.py"
    script.write_text(TRAIN_SCRIPT)
    caches = tmp_path / "caches"
    out = tmp_path / "run"
    hold = tmp_path / "hold"
    hold.touch()
    first = start(train_cmd(script, caches, out), dict(plugin, DOABENCH_TEST_HOLD=str(hold)), tmp_path)
    wait_for(first, lambda: (out / LATEST).is_file(), timeout=600)
    second = subprocess.run(train_cmd(script, caches, out, "--resume"), env=plugin, capture_output=True, text=True,
                            timeout=300)
    hold.unlink()
    assert second.returncode == 2
    assert f"pid {first.pid}" in one_line(second.stderr) and "is writing the training run" in second.stderr
    _, err = first.communicate(timeout=900)
    assert first.returncode == 0, err


# -- two processes, one output ------------------------------------------------------------------------
def test_two_runs_on_one_output_one_proceeds(plugin, straight_run, tmp_path):
    out = tmp_path / "r"
    cmd = doabench(*RUN, "--out", str(out))
    hold = tmp_path / "hold"
    hold.touch()
    first = start(cmd, dict(plugin, DOABENCH_TEST_HOLD=str(hold)), tmp_path)
    wait_for(first, lambda: out.is_dir() and any(out.glob(".*.lock")) and journal_records(out) >= 1)
    second = subprocess.run(cmd, env=plugin, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    hold.unlink()
    assert second.returncode == 2
    line = one_line(second.stderr)
    assert f"pid {first.pid}" in line and "wait for it or stop it" in line
    _, err = first.communicate(timeout=600)
    assert first.returncode == 0, err
    assert scores(json.loads(next(out.glob("*.json")).read_text())) == scores(straight_run)


def test_two_make_datasets_on_one_output_one_proceeds(plugin, tmp_path):
    from doabench.datasets import DatasetFile
    from doabench.datasets.generate import parts_dir

    out = tmp_path / "d.h5"
    cmd = doabench("make-dataset", "--task", "int-tiny-test", "--features", "srp:4x8", "--quiet", "--out", str(out))
    first = start(cmd, plugin, tmp_path)
    wait_for(first, lambda: (parts_dir(out) / "lock").exists())
    second = subprocess.run(cmd, env=plugin, capture_output=True, text=True, timeout=300)
    if second.returncode == 0:  # the first one finished in between: the second found it complete
        assert "already complete" in second.stdout
    else:
        assert second.returncode == 2 and f"pid {first.pid}" in one_line(second.stderr)
    _, err = first.communicate(timeout=600)
    assert first.returncode == 0, err
    with DatasetFile(out) as f:
        assert f.indices == list(range(6))


def test_a_stale_lock_of_a_dead_process_is_taken_over(tmp_path, capsys):
    from doabench.results.writer import results_stem
    from doabench.runner.journal import lock_path

    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    lock = lock_path(tmp_path / f".{results_stem('sim-demo', 'srp-max:4x8')}.partial.jsonl")
    lock.write_text(json.dumps({"pid": dead.pid, "started": "earlier"}) + "\n")  # left by a SIGKILL
    args = ["run", "--tracker", "srp-max:4x8", "--task", "sim-demo", "--episodes", "1", "--out", str(tmp_path),
            "--quiet"]
    assert main(args) == 0, capsys.readouterr().err
    assert not lock.exists() and list(tmp_path.glob("*.json"))


def test_a_held_lock_names_its_owner(tmp_path):
    from doabench.errors import InputError
    from doabench.files import exclusive_lock

    lock = tmp_path / "x.lock"
    with exclusive_lock(lock, "the thing"):
        assert json.loads(lock.read_text())["pid"] == os.getpid()
        holder = subprocess.run([sys.executable, "-c", (
            "import sys\nfrom doabench.files import exclusive_lock\n"
            f"with exclusive_lock({str(lock)!r}, 'the thing'): pass\n")], capture_output=True, text=True,
            cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)))
        assert holder.returncode != 0 and f"pid {os.getpid()}" in holder.stderr
        with pytest.raises(InputError, match=f"pid {os.getpid()}.*the thing"):
            # the same process asking twice is refused too: flock is per open file
            with exclusive_lock(lock, "the thing"):
                pass
    assert not lock.exists()
