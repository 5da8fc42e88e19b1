"""Datasets: make-dataset (schema, shards, workers, SIGKILL + resume), info, merge, EpisodeDataset, file: replay."""
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

import doabench
from doabench.cli.main import main
from doabench.datasets import DatasetFile, EpisodeDataset, make_dataset, merge_datasets
from doabench.datasets.generate import parts_dir, partial_path
from doabench.datasets.layout import read_episode
from doabench.datasets.merge import records_equal
from doabench.datasets.schema import SCHEMA, parse_features, parse_shard, shard_indices
from doabench.envs.env import DoaEnv
from doabench.errors import ConfigError, InputError, NotFoundError

from conftest import ROOT, tiny_task_toml

TASK = "ds-tiny-test"
# 1 s scenes in small, mildly reverberant rooms: about 0.3 s of simulation per episode.
TASK_TOML = tiny_task_toml(TASK, episodes=4, base_seed=777, version=2)
FEATURES = "srp:4x8,srp:8x16,gcc,audio"


@pytest.fixture(scope="module")
def task_dir(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("tasks")
    (folder / f"{TASK}.toml").write_text(TASK_TOML)
    doabench.register_task(folder / f"{TASK}.toml")
    return folder


@pytest.fixture(scope="module")
def reference(task_dir, tmp_path_factory) -> Path:
    """All 4 episodes made at once by one process: what every other way of making them must equal."""
    out = tmp_path_factory.mktemp("ref") / "all.h5"
    make_dataset(TASK, out, features=FEATURES, progress=False)
    return out


def assert_same_episodes(a: Path, b: Path, indices=None) -> None:
    with DatasetFile(a) as fa, DatasetFile(b) as fb:
        assert fa.items == fb.items
        want = fa.indices if indices is None else indices
        assert fb.indices == want or indices is not None
        for i in want:
            ra, rb = read_episode(fa.group(i)), read_episode(fb.group(i))
            assert records_equal(ra, rb), f"episode {i} differs"


def test_feature_and_shard_parsing():
    reqs = parse_features("gcc, srp:16x32,srp:8x16,srp:16x32")
    assert [r.name for r in reqs] == ["srp:8x16", "srp:16x32", "gcc"]
    assert parse_features("srp")[0].name == "srp:16x32"
    for bad in ("srp:16", "mfcc", "gcc:4x8", ""):
        with pytest.raises(ConfigError):
            parse_features(bad)
    assert parse_shard("2/3") == (2, 3) and parse_shard(None) is None
    for bad in ("0/3", "4/3", "a/b", "3"):
        with pytest.raises(ConfigError, match="--shard"):
            parse_shard(bad)
    assert shard_indices(7, (2, 3)) == [1, 4] and shard_indices(3, None) == [0, 1, 2]


def test_file_schema_attributes_and_episode_contents(reference):
    with h5py.File(reference, "r") as f:
        assert f.attrs["doabench_schema"] == SCHEMA
        assert f.attrs["task_id"] == TASK and f.attrs["task_version"] == 2
        config = json.loads(f.attrs["config"])
        assert config["features"] == ["srp:4x8", "srp:8x16", "gcc", "audio"] and config["episodes"] == 4
        assert config["task"]["params"]["scene"]["duration_s"] == 1.0
        versions = json.loads(f.attrs["versions"])
        assert {"doabench", "torch", "numpy"} <= set(versions) and f.attrs["backend"] == "builtin"
        g = f["episodes/000002"]
        assert g.attrs["complete"] and g.attrs["index"] == 2 and "seed" in g.attrs
        srp = g["features/srp_8x16"]
        assert srp.shape[1:] == (8, 16) and srp.dtype == np.float32
        assert srp.chunks == srp.shape and srp.compression == "gzip"  # one chunk per episode dataset
        assert g["features/srp_max_4x8"].shape[1:] == (2,)
        assert g["audio"].shape == (12, 16000) and g["sample_vad"].shape == (16000,)
        assert g["truth/directions"].shape == (srp.shape[0], 3) and g["vad"].dtype == bool
        assert g["scene/room_dims"].shape == (3,) and g["scene/trajectory"].shape == (8, 3)
        assert 0.2 <= g["scene"].attrs["t60"] <= 0.3 and "snr_db" in g["scene"].attrs
        meta = json.loads(g["metadata"][()])
        assert meta["seed"] == g.attrs["seed"] and meta["scene"]["seed"] == g.attrs["seed"]


def _n_axes(axes: str) -> int:
    """Axes named in ``"(frame, [x, y, z])"``: top-level entries; a bracketed list is one axis."""
    inner, depth, entries, current = axes.strip()[1:-1], 0, [], ""
    for ch in inner + ",":
        depth += (ch == "[") - (ch == "]")
        if ch == "," and depth == 0:
            entries.append(current.strip())
            current = ""
        else:
            current += ch
    return len([e for e in entries if e])


def test_every_dataset_names_its_units_and_axes(reference, tmp_path):
    """A file describes itself: each dataset's units and axes (one per dimension) as attributes,
    the truth angles' unit, what srp_max and the trajectory hold, the scene attributes' units."""
    merged = tmp_path / "merged.h5"
    merge_datasets([reference], merged)
    for path in (reference, merged):
        with h5py.File(path, "r") as f:
            assert f["requested"].attrs["axes"] == "(episode,)"
            g = f["episodes/000001"]
            datasets = []
            g.visititems(lambda name, obj: datasets.append((name, obj)) if isinstance(obj, h5py.Dataset) else None)
            assert len(datasets) > 15
            for name, ds in datasets:
                assert isinstance(ds.attrs.get("units"), str) and ds.attrs.get("description"), name
                assert _n_axes(ds.attrs["axes"]) == ds.ndim, (name, ds.attrs["axes"], ds.shape)
            assert g["truth/elevation"].attrs["units"] == g["truth/azimuth"].attrs["units"] == "rad"
            assert "zenith" in g["truth/elevation"].attrs["description"]
            assert g["truth/times"].attrs["units"] == "s" and g["scene/trajectory"].attrs["units"] == "m"
            assert g["features/srp_max_8x16"].attrs["axes"] == "(frame, [elevation, azimuth])"
            assert "not the three components" in g["features/srp_max_8x16"].attrs["description"]
            trajectory = g["scene/trajectory"].attrs
            assert trajectory["axes"].startswith("(trajectory point,") and "differs from the frames" in \
                " ".join(trajectory["description"].split())
            assert json.loads(g["scene"].attrs["units"])["t60"] == "s"


def test_dataset_info_shows_units_and_axes(reference, capsys):
    assert main(["dataset", "info", str(reference)]) == 0
    text = capsys.readouterr().out
    line = next(l for l in text.splitlines() if l.strip().startswith("truth/elevation"))
    assert line.endswith("[rad] (frame,)"), line


def test_stored_features_and_truth_match_the_live_environment(reference):
    env = DoaEnv(TASK, features=("srp", "srp_max", "gcc"), resolution=(8, 16))
    _, feats, truth = env.load_episode(1)
    with DatasetFile(reference) as f:
        stored = f.read(1, ["srp:8x16", "srp_max:8x16", "gcc"])
        stored_truth = f.truth(1)
    # The dataset computes with one torch thread, the environment with the default: last bits may differ.
    np.testing.assert_allclose(stored["srp:8x16"], feats["srp"], atol=1e-5)
    np.testing.assert_allclose(stored["srp_max:8x16"], feats["srp_max"], atol=1e-5)
    np.testing.assert_allclose(stored["gcc"], feats["gcc"], atol=1e-5)
    for k in ("directions", "elevation", "azimuth", "times", "vad"):
        np.testing.assert_array_equal(stored_truth[k], truth[k])


def test_two_shards_merged_equal_one_run_whatever_the_workers(reference, tmp_path):
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    make_dataset(TASK, a, features=FEATURES, shard=(1, 2), progress=False)
    make_dataset(TASK, b, features=FEATURES, shard=(2, 2), workers=2, progress=False)
    with DatasetFile(b) as f:
        assert f.indices == [1, 3]
    assert main(["dataset", "merge", str(a), str(b), "--out", str(tmp_path / "m.h5")]) == 0
    assert_same_episodes(reference, tmp_path / "m.h5")
    with DatasetFile(tmp_path / "m.h5") as f:
        assert f.indices == [0, 1, 2, 3] and f.requested == [0, 1, 2, 3] and f.config["shard"] is None
    # Overlapping identical episodes are kept once; a conflicting one is refused.
    assert merge_datasets([reference, a], tmp_path / "dup.h5")["duplicates"] == 2
    bad = tmp_path / "bad.h5"
    shutil.copy(a, bad)
    with h5py.File(bad, "r+") as f:
        f["episodes/000000/truth/times"][0] += 1.0
    with pytest.raises(InputError, match="episode 0 differs"):
        merge_datasets([reference, bad], tmp_path / "x.h5")
    assert not (tmp_path / "x.h5").exists()


def test_merge_refuses_shards_of_another_config(reference, tmp_path):
    other = tmp_path / "other.h5"
    make_dataset(TASK, other, episodes=1, features="srp:4x8", progress=False)
    with pytest.raises(InputError, match="not a shard of the same dataset.*features"):
        merge_datasets([reference, other], tmp_path / "m.h5")


def _cli(task_dir: Path, out: Path) -> tuple[list[str], dict]:
    cmd = [sys.executable, "-m", "doabench.cli.main", "make-dataset", "--task", TASK, "--features", FEATURES,
           "--out", str(out), "--quiet"]
    env = dict(os.environ, DOABENCH_TASK_PATH=str(task_dir), PYTHONPATH=str(ROOT))
    return cmd, env


def test_sigkill_mid_run_then_resume_equals_an_uninterrupted_run(reference, task_dir, tmp_path):
    out = tmp_path / "killed.h5"
    cmd, env = _cli(task_dir, out)
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    folder = parts_dir(out)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and proc.poll() is None:
        if folder.is_dir() and any(p.name.endswith(".h5") for p in folder.iterdir()):
            break
        time.sleep(0.01)
    assert proc.poll() is None, f"make-dataset ended before it could be killed: {proc.communicate()}"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not out.exists()  # nothing half-written under the final name
    done = [p for p in folder.iterdir() if p.name.endswith(".h5")]
    assert 1 <= len(done) < 4
    # Debris of a crash at other moments: a stray tmp part, a stale assembly, a corrupt part.
    (folder / ".000003.999.tmp").write_bytes(b"half")
    partial_path(out).write_bytes(b"not hdf5")
    missing = sorted({f"{i:06d}.h5" for i in range(4)} - {p.name for p in done})
    (folder / missing[0]).write_bytes(b"\x89HDF\r\n\x1a\n garbage")
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert f"{len(done)} from an earlier run" in res.stdout
    assert out.exists() and not folder.exists() and not partial_path(out).exists()
    assert_same_episodes(reference, out)
    # The same command once more has nothing to do.
    assert make_dataset(TASK, out, features=FEATURES, progress=False).already_complete


def test_resume_with_another_config_is_refused(reference, tmp_path):
    out = tmp_path / "r.h5"

    def crash(index):  # dies after its first episode, leaving the journal behind
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        make_dataset(TASK, out, features="srp:4x8", progress=crash)
    assert not out.exists() and len(list(parts_dir(out).glob("*.h5"))) == 1
    assert main(["dataset", "info", str(out)]) == 0  # reports the unfinished run
    with pytest.raises(ConfigError, match="unfinished run with another config.*features"):
        make_dataset(TASK, out, features="srp:8x16", progress=False)
    make_dataset(TASK, out, features="srp:4x8", progress=False)
    with pytest.raises(InputError, match="exists and was made with another config"):
        make_dataset(TASK, out, features="gcc", progress=False)
    with pytest.raises(ConfigError, match="out of range"):
        make_dataset(TASK, tmp_path / "y.h5", episodes=9, progress=False)


def test_corrupt_and_foreign_files_are_clear_errors(reference, tmp_path):
    cases = {}
    cases["text.h5"] = b"hello, not hdf5"
    cases["truncated.h5"] = reference.read_bytes()[: reference.stat().st_size // 3]
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
    with h5py.File(tmp_path / "foreign.h5", "w") as f:
        f["x"] = 1
    with h5py.File(tmp_path / "v9.h5", "w") as f:
        f.attrs["doabench_schema"] = "doabench.dataset/9"
        f.create_group("episodes")
    expected = {"text.h5": "not an HDF5 file", "truncated.h5": "truncated or corrupt",
                "foreign.h5": "not a doabench dataset", "v9.h5": "schema doabench.dataset/9"}
    for name, message in expected.items():
        with pytest.raises(InputError, match=message) as exc:
            DatasetFile(tmp_path / name)
        assert name in str(exc.value)
    with pytest.raises(NotFoundError, match="does not exist"):
        DatasetFile(tmp_path / "missing.h5")
    assert main(["dataset", "info", str(tmp_path / "text.h5")]) == 2


def test_incomplete_groups_are_not_episodes(reference, tmp_path):
    copy = tmp_path / "c.h5"
    shutil.copy(reference, copy)
    with h5py.File(copy, "r+") as f:
        f["episodes/000001"].attrs["complete"] = False
    with DatasetFile(copy) as f:
        assert f.indices == [0, 2, 3]
        info = f.info()
    assert info["episodes_missing"] == [1] and info["incomplete_groups"] == 1


def test_episode_dataset_items_and_loader(reference):
    ds = EpisodeDataset(reference, features=("srp:8x16", "srp_max:8x16", "gcc"))
    assert len(ds) == 4
    item = ds[2]
    t = item["directions"].shape[0]
    assert item["index"] == 2 and item["features"]["srp:8x16"].shape == (t, 8, 16)
    assert item["features"]["gcc"].dtype == torch.float32 and item["vad"].dtype == torch.bool
    assert item["directions"].shape == (t, 3) and item["times"].shape == (t,)
    loader = torch.utils.data.DataLoader(ds, batch_size=2, num_workers=1)
    batch = next(iter(loader))
    assert batch["features"]["srp:8x16"].shape == (2, t, 8, 16) and batch["index"].tolist() == [0, 1]
    with pytest.raises(NotFoundError, match="does not store feature 'srp:16x32'"):
        EpisodeDataset(reference, features=("srp:16x32",))
    with pytest.raises(NotFoundError, match="does not store"):
        EpisodeDataset(reference, features=("srp",))  # two resolutions stored: ambiguous


def test_float16_maps(tmp_path):
    out = tmp_path / "h.h5"
    make_dataset(TASK, out, episodes=1, features="srp:4x8,gcc", float16=True, compression="lzf", progress=False)
    with h5py.File(out, "r") as f:
        g = f["episodes/000000"]
        assert g["features/srp_4x8"].dtype == np.float16 and g["features/gcc"].dtype == np.float16
        assert g["features/srp_max_4x8"].dtype == np.float32 and g["features/gcc"].compression == "lzf"
    item = EpisodeDataset(out, features="srp")[0]
    assert item["features"]["srp"].dtype == torch.float32


def test_replay_a_dataset_file_as_a_task(reference, tmp_path):
    task = f"file:{reference}"
    spec = doabench.get_task_spec(task)
    assert spec.kind == "dataset" and spec.episodes == 4 and spec.version == 2
    # Stored features are served as they are (no simulation).
    env = DoaEnv(task, features=("srp", "srp_max"), resolution=(8, 16))
    obs, info = env.reset(options={"episode": 3})
    assert type(env._episode).__name__ == "StoredEpisode" and env._episode.n_samples == 16000
    with DatasetFile(reference) as f:
        np.testing.assert_array_equal(obs["srp"], f.read(3, ["srp:8x16"])["srp:8x16"][0])
    assert info["episode"] == 3 and "metadata" not in info  # the scene is not handed out during the episode
    assert env.load_episode(3)[0].metadata["episode_index"] == 3
    _, framed, _ = DoaEnv(task, features=("srp", "audio"), resolution=(8, 16)).load_episode(0)
    assert framed["audio"].shape == (len(framed["srp"]), 12, 4096)  # the env's framed audio observation
    # A resolution that is not stored is computed from the stored audio, like the live task does.
    live = DoaEnv(TASK, features=("srp",), resolution=(2, 4))
    env2 = DoaEnv(task, features=("srp",), resolution=(2, 4))
    _, f1, t1 = live.load_episode(0)
    _, f2, t2 = env2.load_episode(0)
    np.testing.assert_array_equal(f1["srp"], f2["srp"])
    np.testing.assert_allclose(t1["directions"], t2["directions"], atol=1e-6)
    results = doabench.run(tracker="srp-max:8x16", task=task, progress=False, keep_frames=False)
    assert results["summary"]["pooled"]["n_episodes"] == 4
    # Without audio, asking for features the file does not store is a clear error.
    small = tmp_path / "noaudio.h5"
    make_dataset(TASK, small, episodes=1, features="srp:4x8", progress=False)
    with pytest.raises(InputError, match="stores srp:4x8, srp_max:4x8 but the environment asks"):
        DoaEnv(f"file:{small}", features=("srp",), resolution=(8, 16)).reset(options={"episode": 0})
    with pytest.raises(InputError, match="not an HDF5 file"):
        (tmp_path / "junk.h5").write_text("junk")
        doabench.get_task_spec(f"file:{tmp_path / 'junk.h5'}")


def test_cli_make_dataset_and_info(task_dir, tmp_path, capsys):
    out = tmp_path / "cli.h5"
    assert main(["make-dataset", "--task", TASK, "--episodes", "2", "--shard", "2/2", "--features", "srp:4x8",
                 "--sample-vad", "--out", str(out), "--quiet"]) == 0
    assert "wrote" in capsys.readouterr().out
    assert main(["dataset", "info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "1 complete / 1 requested" in text and "features/srp_4x8" in text and "sample_vad" in text
    assert main(["dataset", "info", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["index_range"] == [1, 1]
    assert main(["make-dataset", "--task", TASK, "--features", "mfcc", "--out", str(tmp_path / "e.h5")]) == 2
    assert "unknown dataset feature" in capsys.readouterr().err


def test_replay_of_nan_truth_is_refused_without_results(reference, tmp_path, capsys):
    bad = tmp_path / "nan.h5"
    shutil.copy(reference, bad)
    with h5py.File(bad, "r+") as f:
        d = f["episodes/000001/truth/directions"]
        values = d[()]
        values[2] = np.nan
        d[...] = values
    with DatasetFile(bad) as f:
        f.truth(0)  # the other episodes are fine
        with pytest.raises(InputError, match="episode 1"):
            f.truth(1)
    out = tmp_path / "res"
    code = main(["run", "--tracker", "srp-max:8x16", "--task", f"file:{bad}", "--out", str(out), "--quiet"])
    assert code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not list(out.glob("*.json")) and not list(out.glob("*.csv"))  # no results (the journal of episode 0 stays)


def test_merge_refuses_a_corrupt_chunk_even_with_one_input(reference, tmp_path, capsys):
    bad = tmp_path / "bad.h5"
    shutil.copy(reference, bad)
    with h5py.File(bad, "r") as f:
        d = f["episodes/000002/features/gcc"]
        assert d.compression == "gzip"
        info = d.id.get_chunk_info(0)
    data = bytearray(bad.read_bytes())
    start = info.byte_offset + info.size // 3
    data[start:start + 64] = bytes(64)[:32] + b"\xff" * 32
    bad.write_bytes(bytes(data))
    out = tmp_path / "merged.h5"
    with pytest.raises(InputError, match="episode 2"):
        merge_datasets([bad], out)
    assert main(["dataset", "merge", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not out.exists() and not list(tmp_path.glob("merged*"))


@pytest.mark.parametrize("damage", ["corrupt", "missing"])
def test_journal_parts_of_another_config_are_not_reused(task_dir, tmp_path, damage):
    out = tmp_path / "d.h5"

    def stop(index):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        make_dataset(TASK, out, episodes=2, features="srp:4x8", progress=stop)
    folder = parts_dir(out)
    assert (folder / "000000.h5").exists()
    if damage == "corrupt":
        (folder / "config.json").write_text("{not json")
    else:
        (folder / "config.json").unlink()
    make_dataset(TASK, out, episodes=2, features="gcc", progress=False)
    with h5py.File(out, "r") as f:
        for name in ("000000", "000001"):
            stored = set(f[f"episodes/{name}/features"])
            assert stored == {"gcc"}, (name, stored)
    with DatasetFile(out) as f:
        assert f.items == ["gcc"]


GRID = "ds-grid-tiny-test"
# 6 cells (T60 x SNR) of 2 episodes each, 1 s scenes: the smallest grid to spread episodes over.
GRID_TOML = f"""
id = "{GRID}"
version = 1
kind = "simulated"
base_seed = 4242
[grid]
t60 = [0.2, 0.3]
snr = [10.0, 20.0, 30.0]
episodes_per_cell = 2
cell_id = "{GRID}-t60-{{t60}}-snr-{{snr}}"
[speech]
corpus = "embedded"
[scene]
duration_s = 1.0
n_points = 8
room_max = [5.0, 5.0, 3.0]
"""


@pytest.fixture(scope="module")
def grid_task(tmp_path_factory) -> str:
    folder = tmp_path_factory.mktemp("grid")
    (folder / f"{GRID}.toml").write_text(GRID_TOML)
    doabench.register_task(folder / f"{GRID}.toml")
    return GRID


def test_episodes_spread_over_a_grids_cells_as_run_takes_them(grid_task, tmp_path, capsys):
    """``make-dataset --episodes N`` on a grid takes run's selection (once the first N, all from the
    first cells), says so before it starts, records it, and its shards split that selection."""
    from doabench.envs.selection import select_episodes

    out = tmp_path / "g.h5"
    assert main(["make-dataset", "--task", grid_task, "--episodes", "4", "--features", "srp:4x8", "--out", str(out),
                 "--quiet"]) == 0
    said = capsys.readouterr().out
    assert said.startswith(f"{grid_task}: 4 of 12 episodes, spread over the 6 cells (one each from 4 of them)\n"), said
    expected = select_episodes(doabench.get_task_spec(grid_task), 12, 4)[0]
    assert expected == [0, 4, 6, 10]
    with DatasetFile(out) as f:
        assert f.indices == f.requested == expected and f.config["selection"] == "stratified"
    shards = [tmp_path / "s1.h5", tmp_path / "s2.h5"]
    for k, path in enumerate(shards, start=1):
        make_dataset(grid_task, path, episodes=4, features="srp:4x8", shard=(k, 2), progress=False)
    with DatasetFile(shards[0]) as a, DatasetFile(shards[1]) as b:
        assert a.indices == [0, 6] and b.indices == [4, 10]
    merge_datasets(shards, tmp_path / "merged.h5")
    assert_same_episodes(out, tmp_path / "merged.h5")


def test_a_dataset_begun_with_a_grids_first_episodes_keeps_them(grid_task, tmp_path, monkeypatch):
    """A dataset begun when ``--episodes N`` took a grid's first N (its config has no
    ``selection``) resumes to those episodes and is found complete as it was made, with a note; a
    new output spreads them."""
    import doabench.datasets.generate as generate
    from doabench.envs.selection import select_episodes

    def first_n(spec, total, episodes=None, cells=None):  # the rule make-dataset followed before
        return list(range(episodes)), {"rule": "first", "episodes": episodes, "cells": None}

    def stop(index):  # dies after its first episode, leaving the journal behind
        raise KeyboardInterrupt

    out = tmp_path / "old.h5"
    with monkeypatch.context() as patch:
        patch.setattr(generate, "select_episodes", first_n)
        with pytest.raises(KeyboardInterrupt):
            make_dataset(grid_task, out, episodes=3, features="srp:4x8", progress=stop)
    assert "selection" not in json.loads((parts_dir(out) / "config.json").read_text())
    said: list[str] = []
    resumed = make_dataset(grid_task, out, episodes=3, features="srp:4x8", progress=False, say=said.append)
    assert said == [f"{grid_task}: the first 3 of 12 episodes ({out} was begun with them, before --episodes spread "
                    "over a grid's cells: it keeps them; a new --out spreads them)"]
    assert (resumed.resumed, resumed.computed) == (1, 2)
    with DatasetFile(out) as f:
        assert f.indices == [0, 1, 2] and "selection" not in f.config
    assert make_dataset(grid_task, out, episodes=3, features="srp:4x8", progress=False, say=said.append).already_complete
    assert "it keeps them" in said[-1]
    new = tmp_path / "new.h5"
    make_dataset(grid_task, new, episodes=3, features="srp:4x8", progress=False)
    with DatasetFile(new) as f:
        assert f.indices == select_episodes(doabench.get_task_spec(grid_task), 12, 3)[0] == [2, 6, 10]
