"""scripts/commit_run_state.sh: compacts and commits unfinished runs, keeps run states within
their repository budget, and stops only this checkout's training (a stand-in doabench)."""
from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

FAKE = """#!/usr/bin/env bash
echo "$*" >> "$CALLS"
"""


def git(tree: Path, *args: str) -> str:
    return subprocess.run(["git", *args], cwd=tree, check=True, capture_output=True, text=True).stdout


@pytest.fixture
def tree(tmp_path):
    if shutil.which("bash") is None or shutil.which("git") is None:
        pytest.skip("needs bash and git")
    (tmp_path / "scripts").mkdir()
    shutil.copy(ROOT / "scripts" / "commit_run_state.sh", tmp_path / "scripts")
    fake = tmp_path / "fake-doabench"
    fake.write_text(FAKE)
    fake.chmod(0o755)
    git(tmp_path, "init", "-q")
    git(tmp_path, "config", "user.email", "t@example.org")
    git(tmp_path, "config", "user.name", "t")
    (tmp_path / ".gitignore").write_text("fake-doabench\ncalls.txt\n")
    git(tmp_path, "add", ".")
    git(tmp_path, "commit", "-qm", "start")
    return tmp_path


def add_run(tree: Path, name: str, state_bytes: int) -> Path:
    run = tree / "training-runs" / name
    run.mkdir(parents=True)
    (run / "config.json").write_text('{"tracker": "%s"}' % name)
    (run / "log.csv").write_text("epoch,x\n1,0\n2,0\n")
    (run / "checkpoint.safetensors").write_bytes(os.urandom(state_bytes))  # incompressible, like weights
    return run


def commit_state(tree: Path, *args: str, budget_mb: int = 1) -> subprocess.CompletedProcess:
    env = {**os.environ, "DOABENCH": str(tree / "fake-doabench"), "CALLS": str(tree / "calls.txt"),
           "RUN_STATE_BUDGET_MB": str(budget_mb)}
    return subprocess.run(["bash", str(tree / "scripts" / "commit_run_state.sh"), *args], cwd=tree, env=env,
                          capture_output=True, text=True, check=True)


def test_runs_are_compacted_and_committed_within_the_budget(tree):
    add_run(tree, "a-small", 200_000)
    add_run(tree, "b-large", 900_000)
    done = commit_state(tree)
    calls = (tree / "calls.txt").read_text().splitlines()
    assert sorted(c.split()[2] for c in calls) == ["a-small", "b-large"] and all("--compact" in c for c in calls)
    committed = git(tree, "ls-tree", "-r", "--name-only", "HEAD").split()
    # 0.2 MB fit in the 1 MB budget; the 0.9 MB state after it (glob order) would not: left out, said why
    assert "training-runs/a-small/checkpoint.safetensors" in committed
    assert not any(p.startswith("training-runs/b-large/") for p in committed)
    assert "training-runs/b-large: not committed" in done.stderr and "1 MB budget" in done.stderr
    # what is committed counts against the budget next time; --force overrides it
    assert "not committed" in commit_state(tree).stderr
    commit_state(tree, "--force")
    assert "training-runs/b-large/checkpoint.safetensors" in git(tree, "ls-tree", "-r", "--name-only", "HEAD").split()


def test_training_of_another_checkout_is_left_running(tree):
    other = subprocess.Popen(["bash", "-c", "exec -a 'doabench train --out elsewhere' sleep 30"], cwd="/")
    try:
        add_run(tree, "small", 1000)
        commit_state(tree, "--now")
        assert other.poll() is None  # not this checkout's: still running
    finally:
        other.kill()
        other.wait()


def test_it_waits_for_the_running_run_even_before_its_first_log_line(tree):
    """The run to wait for is the training process's --out, not the newest log.csv: a run in its
    first epoch has none yet, and the newest would be a finished run's."""
    add_run(tree, "finished", 1000)
    (tree / "training-runs" / "starting").mkdir()
    going = subprocess.Popen(["bash", "-c", "exec -a 'doabench train --out training-runs/starting --quiet' sleep 60"],
                             cwd=tree)
    try:
        done = commit_state(tree, "--max-wait", "5")
        assert "waiting for the epoch in progress of training-runs/starting" in done.stdout
        going.wait(timeout=40)  # stopped once the wait is over
    finally:
        going.kill()
        going.wait()
