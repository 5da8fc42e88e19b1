"""scripts/cross3d_targets.py: the issue's targets are read from results files, met or missed."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from doabench.envs.registry import get_task_spec

ROOT = Path(__file__).resolve().parents[1]
CELLS = [(0.0, 5.0), (0.3, 15.0), (0.9, 30.0)]


def _write(folder: Path, task: str, stem: str, per_cell: list[float], nonsilent: float | None = None,
           version: int | None = None) -> None:
    cells = {f"sim-t60-{t}-snr-{s}": {"t60": t, "snr": s, "rmsae_all": v} for (t, s), v in zip(CELLS, per_cell)}
    pooled = sum(per_cell) / len(per_cell)
    result = {"tracker": {"id": stem.replace("_", ":"), "weights_hash": "ab" * 32},
              "task": {"id": task, "version": version if version is not None else get_task_spec(task).version,
                       "episodes_run": 60}, "cells": cells,
              "summary": {"rmsae_all": pooled, "rmsae_nonsilent": nonsilent or pooled}}
    (folder / f"{task}__{stem}.json").write_text(json.dumps(result))


def _run(folder: Path, *args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "scripts" / "cross3d_targets.py"), str(folder), *args],
                          capture_output=True, text=True, timeout=60, env=env)


def _grid(folder: Path, model: list[float]) -> None:
    _write(folder, "sim-grid", "cross3d_16x32", model)
    _write(folder, "sim-grid", "srp-max_16x32", [5.0, 12.0, 20.0])
    _write(folder, "sim-grid", "srp-kalman_32x64", [4.0, 9.0, 15.0])
    _write(folder, "sim-grid", "cross3d_4x8", [9.0, 9.0, 9.0])
    _write(folder, "sim-grid", "max-cnn1d_64x128", [12.0, 12.0, 12.0])


def test_targets_met(tmp_path):
    _grid(tmp_path, [6.0, 8.0, 10.0])  # T60 0 may lose to srp-max; the others win
    _write(tmp_path, "sim-pauses", "cross3d_16x32", [10.0] * 3, nonsilent=8.0)
    _write(tmp_path, "sim-fan", "cross3d_16x32", [12.0] * 3, nonsilent=9.0)
    r = _run(tmp_path)
    assert r.returncode == 0 and "all targets met" in r.stdout, r.stdout + r.stderr


def test_targets_missed_and_missing_are_listed(tmp_path):
    _grid(tmp_path, [6.0, 13.0, 14.0])  # loses to srp-max at T60 0.3; pooled 11 > 10
    _write(tmp_path, "sim-pauses", "cross3d_16x32", [20.0] * 3, nonsilent=8.0)
    r = _run(tmp_path)
    assert r.returncode == 1
    for words in ("pooled sim-grid RMSAE 11.00 > 10", "vs srp-max:16x32 12.00", "sim-pauses: 20.00 > 1.5 x 8.00",
                  "sim-fan results missing"):
        assert words in r.stdout, r.stdout
    # results of an older task version do not count (other episodes): reported as missing
    path = tmp_path / "sim-pauses__cross3d_16x32.json"
    old = json.loads(path.read_text())
    old["task"]["version"] -= 1
    path.write_text(json.dumps(old))
    assert "sim-pauses results missing" in _run(tmp_path).stdout


def test_a_lost_cell_gets_its_paired_difference(tmp_path):
    """With per-episode rows on the same seeds, a cell the model loses is compared pairwise: one
    the model loses in every episode is significant; the 4x8 comparison gets its own line."""
    _grid(tmp_path, [6.0, 8.0, 16.0])  # loses to srp-kalman (15) at T60 0.9
    for stem, per_episode in (("cross3d_16x32", [16.0, 17.0]), ("srp-kalman_32x64", [15.0, 16.0]),
                              ("cross3d_4x8", [9.0, 10.0]), ("max-cnn1d_64x128", [12.0, 8.0])):
        path = tmp_path / f"sim-grid__{stem}.json"
        r = json.loads(path.read_text())
        r["episodes"] = [{"task": "sim-t60-0.9-snr-30.0", "seed": seed, "rmsae_all": v, "n_frames": 100}
                         for seed, v in zip((11, 12), per_episode)]
        path.write_text(json.dumps(r))
    out = _run(tmp_path).stdout
    assert "sim-t60-0.9-snr-30.0, cross3d:16x32 - srp-kalman:32x64: difference +1.00 deg [+1.00, +1.00] " \
           "(paired bootstrap over 2 episodes: significant at 95 %)" in out, out
    assert "cross3d:4x8 - max-cnn1d:64x128: difference -0.68 deg" in out and "a tie at 95 %" in out, out
    # the count of cells won significantly covers the comparisons with per-episode rows only
    assert "significantly lower (95 %) than srp-kalman:32x64 in 0 of the 1 cells compared" in out, out
    assert "than srp-max:16x32" not in out, out


def test_grid_option_checks_the_replica_grid_only(tmp_path):
    """``--grid sim-grid-replica`` reads that task's files (registered from scripts/replica-tasks)
    and leaves sim-pauses and sim-fan out; an unknown grid task is a one-line error, exit 2."""
    import os

    from doabench.envs.spec import load_spec_file

    replica = ROOT / "scripts" / "replica-tasks" / "sim-grid-replica.toml"
    # read, not registered: this process's task registry stays as it is
    version = next(s.version for s in load_spec_file(replica) if s.id == "sim-grid-replica")
    for stem, per_cell in (("cross3d_16x32", [6.0, 13.0, 14.0]), ("srp-max_16x32", [5.0, 12.0, 20.0]),
                           ("srp-kalman_32x64", [4.0, 9.0, 15.0]), ("cross3d_4x8", [9.0] * 3),
                           ("max-cnn1d_64x128", [12.0] * 3)):
        _write(tmp_path, "sim-grid-replica", stem, per_cell, version=version)
    env = {**os.environ, "DOABENCH_TASK_PATH": str(replica.parent)}
    r = _run(tmp_path, "--grid", "sim-grid-replica", env=env)
    assert r.returncode == 1 and "pooled sim-grid-replica RMSAE 11.00 > 10" in r.stdout, r.stdout + r.stderr
    assert "sim-pauses" not in r.stdout and "sim-fan" not in r.stdout
    bad = _run(tmp_path, "--grid", "sim-grid-nope", env=env)
    assert bad.returncode == 2 and "unknown task 'sim-grid-nope'" in bad.stderr and "Traceback" not in bad.stderr


def test_pause_hold_bound(tmp_path):
    """The hold-the-truth oracle: 90° before the first voice-active frame, then the angle the
    source has moved since the last voice-active frame; the tracker's own RMSAE beside it."""
    up, east, north = [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]
    frames = {"truth": [up, up, east, north], "estimates": [up, up, up, north], "vad": [False, True, False, True]}
    path = tmp_path / "r.json"
    path.write_text(json.dumps({"frames": [frames]}))
    script = Path(__file__).resolve().parents[1] / "scripts" / "pause_hold_bound.py"
    out = subprocess.run([sys.executable, str(script), str(path)], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    row = out.stdout.strip().splitlines()[-1].split("|")
    # tracker: errors 0, 0, 90, 0; oracle: 90 (nothing heard yet), 0, 90 (up -> east), 0
    assert [float(x) for x in row[2:5]] == [45.0, 0.0, 63.64]
    # two files pool over their frames: the second one (a perfect tracker, voice from frame 1 on)
    still = {"truth": [up, up], "estimates": [up, up], "vad": [True, True]}
    second = tmp_path / "s.json"
    second.write_text(json.dumps({"frames": [still]}))
    out = subprocess.run([sys.executable, str(script), str(path), str(second)], capture_output=True, text=True)
    row = out.stdout.strip().splitlines()[-1].split("|")
    assert row[1].strip() == "all 2 files, pooled"
    assert [float(x) for x in row[2:5]] == [36.74, 0.0, 51.96]  # sqrt(8100/6), 0, sqrt(16200/6)
    path.write_text(json.dumps({"frames": None}))
    out = subprocess.run([sys.executable, str(script), str(path)], capture_output=True, text=True)
    assert out.returncode == 2 and "no per-frame estimates" in out.stderr


def test_silence_errors_counts_frames_since_voice():
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "scripts" / "silence_errors.py"
    spec = importlib.util.spec_from_file_location("silence_errors", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    vad = np.array([0, 0, 1, 0, 0, 1, 1, 0], bool)
    assert module.frames_since_voice(vad).tolist() == [-1, -1, 0, 1, 2, 0, 0, 1]


def test_silence_errors_splits_a_results_file_by_silence(tmp_path):
    up, east = [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]
    # errors: 90 (before any voice), 0 (voiced), 90, 90 (1 and 2 frames after voice)
    frames = {"truth": [up, up, up, up], "estimates": [east, up, east, east], "vad": [False, True, False, False]}
    path = tmp_path / "r.json"
    path.write_text(json.dumps({"frames": [frames], "tracker": {"id": "t"}, "task": {"id": "x", "version": 1}}))
    script = Path(__file__).resolve().parents[1] / "scripts" / "silence_errors.py"
    out = subprocess.run([sys.executable, str(script), "--results", str(path), "--holds", "1"],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert "all 77.94 deg, non-silent 0.00 deg" in lines[0]
    assert "| before the first voice | 1 | 90.00 | 0.33 |" in lines
    assert "| 1-2 | 2 | 90.00 | 0.67 |" in lines
    assert "| after the first voice (all but the row above) | 3 | 73.48 | 0.67 |" in lines  # 0, 90, 90
    # held after one silent frame: frames 2 and 3 repeat frame 1's estimate (up, error 0)
    assert lines[-1] == "hold after 1 silent frames: all 45.00 deg"
    # several files pool their frames: twice the same file, twice the frames, the same RMSAE
    out = subprocess.run([sys.executable, str(script), "--results", str(path), str(path), "--holds", "1"],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert "t on x v1 and 1 more results files (2 trajectories, 8 frames): all 77.94 deg" in out.stdout, out.stdout


def test_compare_pairs_two_runs_over_their_episodes(tmp_path):
    """--compare: A - B over the episodes both ran, pooled and per cell; a bad file is one line, exit 2."""
    def write(name: str, errors: list[float]) -> Path:
        episodes = [{"task": f"cell-{i % 2}", "seed": i, "rmsae_all": e, "n_frames": 10} for i, e in enumerate(errors)]
        path = tmp_path / name
        path.write_text(json.dumps({"summary": {"rmsae_all": float(np.sqrt(np.mean(np.square(errors)))),
                                                "rmsae_nonsilent": 1.0}, "episodes": episodes}))
        return path

    base = [4.0, 6.0, 5.0, 7.0, 6.0, 8.0, 5.0, 9.0]
    a, b = write("a.json", [e + 2.0 for e in base]), write("b.json", base)
    script = ROOT / "scripts" / "cross3d_targets.py"
    out = subprocess.run([sys.executable, str(script), "--compare", str(a), str(b)], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[2].startswith("a.json - b.json: difference +") and "significant at 95 %" in lines[2], lines
    assert [line.split(":")[0].strip() for line in lines[3:]] == ["cell-0", "cell-1"]
    bad = subprocess.run([sys.executable, str(script), "--compare", str(a), str(tmp_path / "none.json")],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "cannot compare" in bad.stderr and "Traceback" not in bad.stderr
