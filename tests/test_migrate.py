"""Older file formats read through the upgrade (doabench.results.upgrade) and rewritten by
``doabench migrate``: one test per older variant the upgrade reads, every committed results file
read back with the figures it stores, and the command's rewrite, idempotence and bad input."""
from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import pytest

import doabench
from doabench.cli.main import main
from doabench.errors import InputError
from doabench.framing import FrameSpec
from doabench.features.spec import ObservationSpec
from doabench.results.identity import results_delays, results_kinds
from doabench.results.ranking import load_runs
from doabench.results.schema import load_results
from doabench.results.upgrade import (NAMES_BEFORE_RECORDING, RESULTS_SCHEMA, WEIGHTS_FORMAT, UpgradeError,
                                      results_v1_to_v2, upgrade_results, upgrade_weights_metadata)

from conftest import ROOT

COMMITTED = sorted([*(ROOT / "results").glob("*.json"), *(ROOT / "results" / "replica").glob("*.json")])
V1_FILE = ROOT / "results" / "sim-demo__srp-max_16x32.json"


def _v1() -> dict:
    """A committed file of the first schema (the test fails loudly once none is left)."""
    data = json.loads(V1_FILE.read_text())
    assert data["schema"] == "doabench.results/1"
    return data


def _spec(kinds, resolution, window=4096, hop=3072, fs=16000, delays=None) -> dict:
    return doabench.ObservationSpec.of(kinds, resolution, FrameSpec(window, hop, fs), delays).to_dict()


# -- doabench.results/1, one test per older variant --------------------------------------------------
def test_a_features_block_becomes_the_stored_observation_spec() -> None:
    old = _v1()
    old["features"] = {"kinds": ["srp", "srp_max"], "resolution": "8x16", "delays": "exact",
                       "frame": {"window": 2048, "hop": 1024, "fs": 16000}, "trained_delays": "nearest"}
    before = copy.deepcopy(old)
    new = results_v1_to_v2(old)
    assert old == before  # pure: the input is left as it is
    assert new["schema"] == RESULTS_SCHEMA and "features" not in new
    assert new["observations"] == _spec(("srp", "srp_max"), (8, 16), 2048, 1024, delays="exact")
    assert new["trained_delays"] == "nearest" and results_delays(new) == "exact"
    assert ObservationSpec.from_dict(new["observations"]).frame_spec == FrameSpec(2048, 1024, 16000)


def test_a_learned_trackers_trained_features_become_its_weights_spec() -> None:
    old = json.loads((ROOT / "results" / "sim-grid__cross3d_8x16__paper.json").read_text())
    assert old["schema"] == "doabench.results/1" and "window" in old["tracker"]["trained_features"]
    new = upgrade_results(old)
    assert new["tracker"]["trained_features"] == _spec(("srp", "srp_max"), (8, 16), delays="nearest")


def test_a_bare_tracker_id_gets_the_resolution_it_ran_at() -> None:
    old = _v1()
    old["tracker"] = {**old["tracker"], "id": "srp-max", "resolution": "16x32"}
    old["tracker"].pop("resolution_in_id", None)
    assert upgrade_results(old)["tracker"]["id"] == "srp-max:16x32"
    old["tracker"]["resolution_in_id"] = False  # a spec that is not the map resolution stays as it is
    assert upgrade_results(old)["tracker"]["id"] == "srp-max"


def test_weights_written_before_their_name_was_recorded_are_named_by_their_hash() -> None:
    (tracker, digest), name = next(iter(NAMES_BEFORE_RECORDING.items()))
    old = _v1()
    old["tracker"] = {**old["tracker"], "id": tracker, "weights_hash": digest}
    old["tracker"].pop("weights_name", None)
    assert upgrade_results(old)["tracker"]["weights_name"] == name
    old["tracker"]["weights_hash"] = "0" * 64  # weights that did not ship then: no name
    assert upgrade_results(old)["tracker"]["weights_name"] is None
    old["tracker"]["weights_hash"] = None
    assert upgrade_results(old)["tracker"]["weights_name"] is None


def test_task_options_are_read_back_from_the_source() -> None:
    old = _v1()
    assert "options" not in old["task"]
    old["task"]["source"] = {**old["task"]["source"], "simulator": "pyroomacoustics"}
    assert upgrade_results(old)["task"]["options"] == {"backend": "pyroomacoustics"}


def test_an_interval_of_no_width_written_before_the_rule_becomes_none() -> None:
    """Files written before ``defined_interval`` held an interval of no width where the episodes
    back none; the upgrade drops it (null, printed n/a), a backed interval is kept."""
    from doabench.results.intervals import shown_interval

    old = _v1()
    assert len(old["episodes"]) >= 3 and len({row["rmsae_all"] for row in old["episodes"]}) > 1
    value = old["summary"]["rmsae_all"]
    old["summary"]["rmsae_all_ci95"] = [value, value]  # no width, yet the episodes differ
    new = upgrade_results(old)
    assert new["summary"]["rmsae_all_ci95"] is None and shown_interval(new, "rmsae_all") is None
    kept = old["summary"]["rmsae_nonsilent_ci95"]
    assert new["summary"]["rmsae_nonsilent_ci95"] == kept and shown_interval(new, "rmsae_nonsilent") == tuple(kept)


def test_an_unreadable_features_block_is_one_line_and_the_leaderboard_skips_the_file(tmp_path: Path) -> None:
    old = _v1()
    old["features"]["frame"] = {"window": "wide"}  # a kind's name is text (a plug-in's is never looked up); frames are numbers
    with pytest.raises(UpgradeError, match="doabench.results/1 results file that cannot be read") as info:
        upgrade_results(old)
    assert "\n" not in str(info.value)
    (tmp_path / "bad.json").write_text(json.dumps(old))
    (tmp_path / V1_FILE.name).write_bytes(V1_FILE.read_bytes())
    warnings: list[str] = []
    runs = load_runs(tmp_path, warn=warnings.append)
    assert [Path(r.path).name for r in runs] == [V1_FILE.name]
    assert len(warnings) == 1 and "bad.json" in warnings[0] and "features block" in warnings[0]
    with pytest.raises(InputError, match="bad.json"):
        load_results(tmp_path / "bad.json")


def test_the_current_schema_and_foreign_files_pass_as_they_are() -> None:
    new = upgrade_results(_v1())
    assert upgrade_results(new) == new
    for other in ({"schema": "doabench.results/9"}, {"schema": "other/1"}, [1, 2], {"no": "schema"}):
        assert upgrade_results(other) == other


# -- every committed results file --------------------------------------------------------------------
def _same(a, b) -> bool:
    """Equal JSON values, NaN equal to NaN."""
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return a == b


@pytest.mark.parametrize("path", COMMITTED, ids=lambda p: p.name)
def test_committed_results_read_back_with_the_figures_they_store(path: Path) -> None:
    """The summary (every figure the leaderboards show), the cells and the episode rows read
    through the upgrade are the raw file's; the delays and kinds are those its features named."""
    raw = json.loads(path.read_text())
    read = load_results(path)
    assert read["schema"] == RESULTS_SCHEMA
    for key in ("summary", "cells", "episodes", "scoring", "environment"):
        assert _same(read.get(key), raw.get(key)), key
    if "features" in raw:
        spec = ObservationSpec.from_dict(read["observations"])
        assert results_delays(read) == raw["features"]["delays"]
        assert results_kinds(read) == list(spec.kind_names) == raw["features"]["kinds"]
        assert spec.frame_spec.to_dict() == raw["features"]["frame"]


def test_the_leaderboard_of_the_committed_results_reads_every_file() -> None:
    warnings: list[str] = []
    runs = load_runs([ROOT / "results", ROOT / "results" / "replica"], warn=warnings.append)
    assert not warnings and len(runs) == len(COMMITTED)


# -- weights metadata ---------------------------------------------------------------------------------
def _weights_v1(**extra) -> dict:
    return {"format": "doabench-weights/1", "model": "cross3d", "resolution": "8x16",
            "model_config": {"resolution": "8x16"}, "array": {"name": "nao", "positions": [[0, 0, 0]]},
            "features": {"kinds": ["srp", "srp_max"], "window": 4096, "hop": 3072, "fs": 16000,
                         "delay_mode": "nearest"}, "training": {}, **extra}


def test_weights_v1_features_and_resolution_blocks_become_the_stored_spec() -> None:
    old = _weights_v1()
    new = upgrade_weights_metadata(old)
    assert old["format"] == "doabench-weights/1"  # pure
    assert new["format"] == WEIGHTS_FORMAT and "features" not in new and "resolution" not in new
    assert new["observations"] == _spec(("srp", "srp_max"), (8, 16), delays="nearest")
    assert new["model_config"] == {"resolution": "8x16"}


def test_weights_v1_with_an_observations_block_keep_it_in_the_current_form() -> None:
    stored = {"kinds": ["srp"], "resolution": "4x8", "delays": "exact",
              "frame": {"window": 2048, "hop": 512, "fs": 16000}}
    new = upgrade_weights_metadata(_weights_v1(observations=stored))
    assert new["observations"] == _spec(("srp",), (4, 8), 2048, 512, delays="exact")


def test_weights_v1_of_a_model_without_maps_keep_no_resolution() -> None:
    old = _weights_v1(model="gcc-cnn1d", resolution=None, model_config={})
    old["features"]["kinds"] = ["gcc"]
    new = upgrade_weights_metadata(old)
    assert new["model_config"] == {} and new["observations"] == _spec(("gcc",), None, delays="nearest")


def test_weights_metadata_of_unknown_or_broken_formats_is_one_line() -> None:
    with pytest.raises(UpgradeError, match="unknown metadata format 'other/9'"):
        upgrade_weights_metadata({"format": "other/9"})
    broken = _weights_v1()
    del broken["features"]["hop"]
    with pytest.raises(UpgradeError, match="doabench-weights/1 metadata that cannot be read"):
        upgrade_weights_metadata(broken)


def test_every_shipped_weights_file_reads_as_its_features_said() -> None:
    """Older files (doabench-weights/1, flat ``features``) upgrade to what they said; files written
    in the current format read back their stored observations as they are."""
    from safetensors import safe_open

    from doabench_baselines import weights as W

    older = 0
    for path in sorted(W.SHIPPED_DIR.glob("*.safetensors")):
        with safe_open(str(path), framework="pt", device="cpu") as f:
            raw = json.loads(f.metadata()["doabench"])
        read = W.WeightsFile.read(path)
        assert read.metadata["format"] == W.FORMAT == WEIGHTS_FORMAT
        if raw["format"] == WEIGHTS_FORMAT:
            assert read.observations.to_dict() == raw["observations"], path.name
            continue
        older += 1
        assert read.frame_spec == FrameSpec(raw["features"]["window"], raw["features"]["hop"], raw["features"]["fs"])
        assert read.delay_mode == raw["features"]["delay_mode"]
        if raw["resolution"]:
            assert read.resolution == doabench.trackers.parse_resolution(raw["resolution"]), path.name
    assert older >= 1  # the upgrade is exercised on real files


def test_loading_weights_compares_their_stored_spec_with_the_trackers() -> None:
    from doabench.errors import ConfigError
    from doabench_baselines import weights as W

    path = W.SHIPPED_DIR / "cross3d-4x8.safetensors"
    stored = W.WeightsFile.read(path).observations
    state, _ = W.load_weights(path, observations=stored)  # what the tracker reads: they load
    assert state
    other = doabench.ObservationSpec.of(("srp", "srp_max"), (4, 8), FrameSpec(2048, 1024, 16000))
    with pytest.raises(ConfigError, match="was trained on the observations"):
        W.load_weights(path, observations=other)
    tracker = doabench.make_tracker("cross3d:4x8")
    assert tracker.observation_spec == stored


# -- doabench migrate ---------------------------------------------------------------------------------
def _folder(tmp_path: Path) -> Path:
    folder = tmp_path / "r"
    folder.mkdir()
    for name in (V1_FILE.name, "sim-grid__cross3d_8x16__paper.json"):
        source = ROOT / "results" / name
        (folder / name).write_bytes(source.read_bytes())
        (folder / name).with_suffix(".csv").write_bytes(source.with_suffix(".csv").read_bytes())
    return folder


def test_migrate_rewrites_older_files_in_place_and_is_idempotent(tmp_path: Path, capsys) -> None:
    folder = _folder(tmp_path)
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    assert main(["migrate", str(folder), "--dry-run"]) == 0
    assert "2 files to rewrite" in capsys.readouterr().out
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before  # --dry-run changes nothing
    assert main(["migrate", str(folder)]) == 0
    out = capsys.readouterr().out
    assert out.count(f"doabench.results/1 -> {RESULTS_SCHEMA}") == 2  # a line per file
    for name, data in before.items():
        path = folder / name
        if name.endswith(".csv"):
            assert path.read_bytes() == data  # the CSV twins keep their format: untouched
            continue
        rewritten = json.loads(path.read_text())
        assert rewritten["schema"] == RESULTS_SCHEMA and "features" not in rewritten
        assert _same(rewritten, upgrade_results(json.loads(data)))
    assert not list(folder.glob(".*"))  # no temporary file left
    snapshot = {p.name: p.read_bytes() for p in folder.iterdir()}
    assert main(["migrate", str(folder)]) == 0
    assert f"every results file is in {RESULTS_SCHEMA} and has its current name" in capsys.readouterr().out
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == snapshot
    assert len(load_runs(folder)) == 2


@pytest.mark.parametrize("setup,message", [
    (lambda f: f / "missing", "is not a folder of results files"),
    (lambda f: (f / "notes.json").write_text("[1, 2]") and f, "notes.json is not a doabench results file"),
    (lambda f: (f / "x.json").write_text(json.dumps({**_v1(), "features": {"kinds": "srp"}})) and f,
     "x.json: a doabench.results/1 results file that cannot be read"),
])
def test_migrate_refuses_bad_input_in_one_line(tmp_path: Path, capsys, setup, message) -> None:
    folder = _folder(tmp_path)
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    target = setup(folder)
    capsys.readouterr()
    assert main(["migrate", str(target)]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert all((folder / n).read_bytes() == b for n, b in before.items())  # nothing rewritten


def test_migrate_writes_a_current_copy_of_a_weights_file(tmp_path: Path, capsys) -> None:
    from doabench.provenance import sha256_file
    from doabench_baselines import weights as W

    source = W.SHIPPED_DIR / "cross3d-4x8.safetensors"
    copy_path = tmp_path / "c.safetensors"
    assert main(["migrate", str(source), "--out", str(copy_path)]) == 0
    out = capsys.readouterr().out
    digest = sha256_file(copy_path)
    assert f"sha256 {digest}" in out and "doabench-weights/1" in out
    with __import__("safetensors").safe_open(str(copy_path), framework="pt", device="cpu") as f:
        header = f.metadata()
    assert set(header) == {"doabench", "model"} and json.loads(header["doabench"])["format"] == WEIGHTS_FORMAT
    shipped, _ = W.load_weights(source)
    copied, meta = W.load_weights(copy_path)
    assert shipped.keys() == copied.keys() and all(bool((shipped[k] == copied[k]).all()) for k in shipped)
    assert meta == W.read_metadata(source)  # the same metadata, read from the old format or written in the new
    assert main(["migrate", str(copy_path), "--out", str(tmp_path / "again.safetensors")]) == 0
    assert "already: nothing written" in capsys.readouterr().out and not (tmp_path / "again.safetensors").exists()
    (tmp_path / "bad.safetensors").write_text("not a safetensors file")
    assert main(["migrate", str(tmp_path / "bad.safetensors"), "--out", str(tmp_path / "x.safetensors")]) == 2
    err = capsys.readouterr().err
    assert "not a safetensors file" in err and err.count("\n") == 1
