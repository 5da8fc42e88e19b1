"""baselines/ keeps one tracker per module (as pyroomacoustics keeps one algorithm per module), and
the jobs around a learned tracker are values of their own: the weights file, the hold rule."""
from __future__ import annotations

import importlib
import inspect
import re

import numpy as np
import pytest

from conftest import ROOT

TRACKER_MODULES = {"cross3d": "cross3d", "gcc-cnn1d": "gcc_cnn1d", "max-cnn1d": "max_cnn1d",
                   "spec-cnn2d": "spec_cnn2d", "seldnet": "seldnet"}


def test_one_tracker_per_module():
    folder = ROOT / "baselines" / "trackers"
    registered = {path.stem: re.findall(r'register_tracker\("([^"]+)"\)', path.read_text(encoding="utf-8"))
                  for path in folder.glob("*.py")}
    assert {m: ids for m, ids in registered.items() if ids} == {m: [i] for i, m in TRACKER_MODULES.items()}
    for tracker_id, module in TRACKER_MODULES.items():
        classes = [c for _, c in inspect.getmembers(importlib.import_module(f"doabench_baselines.trackers.{module}"),
                                                    inspect.isclass) if c.__module__.endswith(f".{module}")]
        assert [c.name for c in classes] == [tracker_id]


def test_the_shared_tracker_leaves_weights_and_holding_to_their_own_values():
    from doabench_baselines.trackers.neural import NeuralTracker

    source = inspect.getsource(NeuralTracker)
    for job in ("read_metadata", "check_metadata", "sha256_file", "catalog.resolve", "torch.device(",
                "_silent_run", "stream_chunk"):
        assert job not in source, f"NeuralTracker does {job} itself again"


def test_a_weights_file_is_found_by_name_verified_and_described():
    from doabench_baselines import catalog

    moving = catalog.find_weights("cross3d", (16, 32), "moving")
    entry = catalog.named_weights("cross3d", (16, 32))["moving"]
    assert moving.path == entry.path and moving.sha256 == entry.sha256
    assert moving.resolution == (16, 32) and moving.frame_spec.window == 4096 and moving.delay_mode == "nearest"
    assert moving.describe()["weights"] == str(entry.path) and moving.array.n_mics == 12
    same = catalog.find_weights("cross3d", (16, 32), str(entry.path))  # by path: the same file, the same hash
    assert same.sha256 == moving.sha256
    with pytest.raises(Exception, match="holds a 'cross3d' model, not 'max-cnn1d'"):
        catalog.find_weights("max-cnn1d", (64, 128), str(entry.path))


def test_which_weights_is_answered_by_the_catalog_alone():
    """The learned trackers ask the catalog which weights they run (names, files, SHA-256, the
    default) and work none of it out themselves; tests/test_architecture.py checks that the
    catalog builds on the weights files' module and never the other way."""
    from doabench_baselines.trackers.neural import NeuralTracker

    source = inspect.getsource(NeuralTracker)
    for derived in ("all_named(", "named_weights(", "read_catalog(", "read_manifest(", "SHIPPED_DIR", "WeightsFile"):
        assert derived not in source, f"NeuralTracker works out {derived} itself instead of asking the catalog"


def test_the_hold_rule_step_by_step_equals_the_whole_episode():
    from doabench_baselines.hold import SilenceHold, parse_hold

    rng = np.random.default_rng(0)
    directions = rng.normal(size=(200, 3))
    vad = np.repeat(rng.random(20) < 0.5, 10)
    vad[:7] = False  # silence before the first word: nothing to hold, the model's output passes
    hold = SilenceHold(4)
    stepped = np.stack([hold.step(d, bool(v)) for d, v in zip(directions, vad)])
    assert np.array_equal(stepped, hold.episode(directions, vad))
    assert np.array_equal(stepped[:7], directions[:7])
    assert parse_hold("auto") is None and parse_hold("off") == 0 and parse_hold(3) == 3
