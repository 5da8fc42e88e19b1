"""scripts/train_queue.sh: order, resume and exports, with a stand-in doabench
that records its calls (the real runs take hours)."""
from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

FAKE = """#!/usr/bin/env bash
echo "$*" >> "$CALLS"
out=""; export_to=""
while [ $# -gt 0 ]; do
    case "$1" in --out) out="$2"; shift ;; --export) export_to="$2"; shift ;; esac
    shift
done
if [ -n "$export_to" ]; then echo weights > "$export_to"; fi
if [ -z "$export_to" ] && [ -n "$out" ]; then mkdir -p "$out"; echo state > "$out/checkpoint.safetensors"; fi
"""


@pytest.fixture
def tree(tmp_path):
    if shutil.which("bash") is None:
        pytest.skip("needs bash")
    (tmp_path / "scripts").mkdir()
    shutil.copy(ROOT / "scripts" / "train_queue.sh", tmp_path / "scripts")
    (tmp_path / "baselines" / "weights").mkdir(parents=True)
    fake = tmp_path / "fake-doabench"
    fake.write_text(FAKE)
    fake.chmod(0o755)
    return tmp_path


def run_queue(tree: Path) -> list[str]:
    env = {**os.environ, "DOABENCH": str(tree / "fake-doabench"), "CALLS": str(tree / "calls.txt"),
           "DOABENCH_LIBRISPEECH": "/libri"}
    subprocess.run(["bash", str(tree / "scripts" / "train_queue.sh")], check=True, env=env, capture_output=True)
    return (tree / "calls.txt").read_text().splitlines()


def test_queue_skips_exported_runs_resumes_and_exports_in_order(tree):
    done = tree / "training-runs" / "cross3d-16x32"
    done.mkdir(parents=True)
    (done / "exported.txt").write_text("exported\n")
    half = tree / "training-runs" / "cross3d-8x16"
    half.mkdir()
    (half / "checkpoint.safetensors").write_text("state\n")
    calls = run_queue(tree)
    trains = [c for c in calls if "--export" not in c]
    assert [c.split()[2] for c in trains] == ["cross3d:8x16", "cross3d:4x8", "gcc-cnn1d", "max-cnn1d:64x128",
                                               "spec-cnn2d", "seldnet"]
    assert all("--preset paper" in c and "weights=random" in c and "--librispeech /libri" in c for c in trains)
    assert "--resume" in trains[0] and all("--resume" not in c for c in trains[1:])
    exports = [c.split("--export ")[1] for c in calls if "--export" in c]
    assert exports == ["baselines/weights/cross3d-8x16.safetensors", "baselines/weights/cross3d-4x8.safetensors",
                       "baselines/weights/gcc-cnn1d.safetensors", "baselines/weights/max-cnn1d-64x128.safetensors",
                       "baselines/weights/spec-cnn2d.safetensors", "baselines/weights/seldnet.safetensors"]
    for name in ("cross3d-8x16", "max-cnn1d-64x128", "seldnet"):
        run = tree / "training-runs" / name
        assert (run / "exported.txt").exists() and not (run / "checkpoint.safetensors").exists()
    assert "paper preset" in (tree / "training-runs" / "seldnet" / "exported.txt").read_text()
    # a second call finds every run exported and trains nothing
    (tree / "calls.txt").write_text("")
    assert run_queue(tree) == []
