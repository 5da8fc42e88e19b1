"""Leaderboard rows of learned trackers say whether the task is in their training distribution
(same simulator, array and scene family) or zero-shot."""
from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from doabench.reporting.distribution import IN, OUT, training_distribution

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def learned() -> dict:
    path = ROOT / "results" / "sim-grid__cross3d_16x32__paper.json"
    if not path.is_file():
        pytest.skip("shipped results not present")
    return json.loads(path.read_text())


def _on(results: dict, task: str, kind: str = "simulated", **source) -> dict:
    r = copy.deepcopy(results)
    r["task"] = {"id": task, "kind": kind, "source": source}
    return r


def test_the_paper_grid_is_in_distribution_and_moving_scenes_are_not(learned):
    assert training_distribution(learned).status == IN
    assert training_distribution(_on(learned, "sim-pauses")).status == IN
    walk = training_distribution(_on(learned, "sim-walk"))
    assert walk.status == OUT and "walking talkers" in walk.why and walk.text.startswith("zero-shot")
    assert "moving or turning arrays" in training_distribution(_on(learned, "sim-turn")).why
    other_simulator = training_distribution(_on(learned, "sim-grid", simulator="pyroomacoustics"))
    assert other_simulator.status == OUT and "pyroomacoustics" in other_simulator.why
    assert "recorded audio" in training_distribution(_on(learned, "locata-3", kind="locata")).why
    # an override that makes the talker walk takes the task out of the family
    assert training_distribution(_on(learned, "sim-grid", scene_overrides={"walk_p": 1.0})).status == OUT


def test_trackers_without_a_training_record_get_no_mark(learned):
    classical = copy.deepcopy(learned)
    classical["tracker"].pop("training")
    assert training_distribution(classical) is None


def test_leaderboard_rows_carry_the_mark(learned, tmp_path):
    from doabench.reporting.leaderboard import build_leaderboards

    (tmp_path / "a.json").write_text(json.dumps(learned))
    files = build_leaderboards(tmp_path)
    page = files["sim-grid.md"]
    assert "`cross3d:16x32 (weights=paper)` (in-distribution)" in page
    assert "Training tasks: `cross3d:16x32 (weights=paper)` sim-train v1" in page
    assert ",in (sim-train v1)" in files["sim-grid.csv"]
