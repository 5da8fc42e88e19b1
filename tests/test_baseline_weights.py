"""Weight files of the neural trackers: round trip, metadata checks, shipped-weights lookup."""
from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
import torch

import doabench
from doabench.errors import ConfigError, InputError, NotFoundError
from doabench_baselines import catalog as C
from doabench_baselines import weights as W
from doabench_baselines.cross3d import Cross3D
from doabench_baselines.trackers.cross3d import Cross3DTracker
from doabench_baselines.trackers.max_cnn1d import MaxCnn1dTracker



def _untrained(cls, *args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return cls(*args, **kwargs)


@pytest.fixture
def cross3d_file(tmp_path):
    tracker = _untrained(Cross3DTracker, "4x8", weights="random", seed=3)
    path = tracker.save_weights(tmp_path / "cross3d-4x8.safetensors",
                                {"training": {"epochs": 80, "batch": 5}, "torch_version": torch.__version__})
    return tracker, path


def _episode(n=35, res=(4, 8), seed=0):
    rng = np.random.default_rng(seed)
    return {"srp": rng.standard_normal((n,) + res).astype(np.float32),
            "srp_max": rng.random((n, 2)).astype(np.float32), "vad": np.ones(n)}


def test_round_trip_gives_the_same_directions_and_metadata(cross3d_file):
    original, path = cross3d_file
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a trained tracker does not warn
        loaded = Cross3DTracker(weights=str(path))
    assert loaded.resolution == (4, 8)  # taken from the file
    nao = doabench.get_array("nao")
    ep = _episode()
    original.reset(nao)
    loaded.reset(nao)
    np.testing.assert_array_equal(original.track(ep), loaded.track(ep))
    d = loaded.describe()
    assert d["trained"] is True and d["weights_hash"] == W.sha256_file(path)
    assert d["parameters"] == 526_372 and d["training"] == {"epochs": 80, "batch": 5}
    assert d["trained_features"] == doabench.ObservationSpec.of(("srp", "srp_max"), (4, 8)).to_dict()
    meta = W.read_metadata(path)
    assert meta["model"] == "cross3d" and meta["format"] == W.FORMAT == "doabench-weights/2"
    assert "features" not in meta and "resolution" not in meta and meta["array"]["name"] == "nao"
    assert doabench.ObservationSpec.from_dict(meta["observations"]).resolution == (4, 8)
    assert meta["doabench_version"] == doabench.__version__ and meta["date"]
    assert meta["torch_version"] == torch.__version__  # caller keys are kept


def test_resolution_mismatch_is_a_config_error(cross3d_file):
    _, path = cross3d_file
    with pytest.raises(ConfigError, match="trained on 4x8 maps, not 8x16"):
        Cross3DTracker("8x16", weights=str(path))


def test_model_mismatch_is_a_config_error(cross3d_file):
    _, path = cross3d_file
    with pytest.raises(ConfigError, match="holds a 'cross3d' model, not 'max-cnn1d'"):
        MaxCnn1dTracker(weights=str(path))


def test_array_mismatch_is_a_config_error_at_reset(cross3d_file):
    _, path = cross3d_file
    tracker = Cross3DTracker(weights=str(path))
    nao = doabench.get_array("nao")
    tracker.reset(nao.with_positions(nao.positions + 0.002, "measured"))  # within 5 mm: fine
    moved = nao.with_positions(nao.positions + np.array([0.01, 0.0, 0.0]), "moved")
    with pytest.raises(ConfigError, match="differs by up to 10.0 mm"):
        tracker.reset(moved)
    three = doabench.MicArray("three", np.eye(3) * 0.05)
    with pytest.raises(ConfigError, match="12 microphones"):
        tracker.reset(three)


def test_frame_and_delay_mismatch_are_config_errors(cross3d_file):
    _, path = cross3d_file
    with pytest.raises(ConfigError, match="frames"):
        W.load_weights(path, frame_spec=doabench.FrameSpec(window=2048))
    with pytest.raises(ConfigError, match="'nearest' SRP delays, not 'exact'"):
        W.load_weights(path, delay_mode="exact")
    state, meta = W.load_weights(path, model_name="cross3d", resolution=(4, 8),
                                 frame_spec=doabench.FrameSpec(), delay_mode="nearest")
    assert meta["parameters"] == 526_372 and all(isinstance(v, torch.Tensor) for v in state.values())


def test_state_that_does_not_fit_the_model_is_a_config_error(cross3d_file):
    _, path = cross3d_file
    state, _ = W.load_weights(path)
    with pytest.raises(ConfigError, match="shape"):
        W.load_into(Cross3D(4, 16), state, path)  # same layers, wider 1D input
    with pytest.raises(ConfigError, match="missing"):
        W.load_into(Cross3D(4, 8), {k: v for k, v in state.items() if "hidden" not in k}, path)


def test_bad_files(tmp_path):
    with pytest.raises(NotFoundError):
        W.read_metadata(tmp_path / "absent.safetensors")
    junk = tmp_path / "junk.safetensors"
    junk.write_bytes(b"not a safetensors file")
    with pytest.raises(InputError, match="not a safetensors file"):
        W.read_metadata(junk)
    from safetensors.torch import save_file

    bare = tmp_path / "bare.safetensors"
    save_file({"w": torch.zeros(2)}, str(bare))
    with pytest.raises(InputError, match="no doabench metadata"):
        Cross3DTracker(weights=str(bare))
    odd = tmp_path / "odd.safetensors"
    save_file({"w": torch.zeros(2)}, str(odd), metadata={"doabench": json.dumps({"format": "other/9"})})
    with pytest.raises(InputError, match="unknown metadata format"):
        W.read_metadata(odd)


def test_shipped_weights_are_found_and_set_the_default_resolution(tmp_path, monkeypatch):
    monkeypatch.setattr(W, "SHIPPED_DIR", tmp_path)
    with pytest.warns(UserWarning, match="trained: false"):
        assert Cross3DTracker().resolution == (8, 16)  # nothing shipped: the documented default
    _untrained(Cross3DTracker, "4x8", weights="random").save_weights(tmp_path / "cross3d-4x8.safetensors")
    tracker = Cross3DTracker()
    assert tracker.resolution == (4, 8) and tracker.trained
    assert C.shipped_resolutions("cross3d") == [(4, 8)] and C.default_resolution("cross3d") == (4, 8)
    assert not _untrained(Cross3DTracker, "4x8", weights="random").trained  # weights=random overrides


def _scaled_copy(tracker, path, tmp_path, factor):
    state, meta = W.load_weights(path)
    from safetensors.torch import save_file

    bad = {k: (v * factor if v.is_floating_point() else v) for k, v in state.items()}
    name = list(bad)[0]
    if factor != factor:  # NaN: only one value
        bad = dict(state)
        t = bad[name].clone()
        t.view(-1)[0] = float("nan")
        bad[name] = t
    out = tmp_path / f"bad-{factor}.safetensors"
    save_file(bad, str(out), metadata={"doabench": json.dumps(meta)})
    return out


@pytest.mark.parametrize("factor", [float("nan"), 1e30])
def test_weights_with_nan_or_huge_values_are_refused(cross3d_file, tmp_path, factor):
    tracker, path = cross3d_file
    bad = _scaled_copy(tracker, path, tmp_path, factor)
    with pytest.raises(InputError):
        W.load_weights(bad)
    with pytest.raises(InputError):
        Cross3DTracker("4x8", weights=str(bad))


def test_shipped_weights_are_checked_against_the_manifest(tmp_path, monkeypatch):
    monkeypatch.setattr(W, "SHIPPED_DIR", tmp_path)
    path = _untrained(Cross3DTracker, "4x8", weights="random").save_weights(tmp_path / "cross3d-4x8.safetensors")
    assert W.read_manifest(tmp_path)["cross3d-4x8.safetensors"] == W.sha256_file(path)
    assert Cross3DTracker().trained  # listed and intact: loads
    data = bytearray(path.read_bytes())
    data[-100] ^= 0x01  # one flipped bit in the tensor data
    path.write_bytes(bytes(data))
    with pytest.raises(InputError):
        Cross3DTracker()
    (tmp_path / "SHA256SUMS").unlink()
    with pytest.raises(InputError):
        W.load_weights(path)


def test_the_real_shipped_files_match_their_manifest():
    manifest = W.read_manifest()
    shipped = sorted(p.name for p in W.SHIPPED_DIR.glob("*.safetensors"))
    assert shipped and sorted(manifest) == shipped
    for name in shipped:
        W.verify_shipped(W.SHIPPED_DIR / name)


def test_a_nan_network_output_is_an_error_not_a_held_direction(cross3d_file):
    from doabench.errors import TrackerError

    tracker, _ = cross3d_file
    with pytest.raises(TrackerError):
        tracker.direction_from_output(np.array([np.nan, 0.0, 0.0]))
    np.testing.assert_allclose(tracker.direction_from_output(np.array([1e200, 0.0, 0.0])), [1, 0, 0])
    np.testing.assert_allclose(tracker.direction_from_output(np.zeros(3)), [1, 0, 0])  # zero: the previous one is kept


#: the shipped folder (tests below put a copy in its place)
SHIPPED = W.SHIPPED_DIR


def _weights_folder(tmp_path, monkeypatch, entries=(), edit=None):
    """A copy of the shipped folder holding the paper weights of cross3d:16x32, its manifest and its
    catalog, with ``entries`` added to the catalog (then ``edit(catalog)``), used as the shipped folder."""
    import shutil

    folder = tmp_path / "weights"
    folder.mkdir(exist_ok=True)
    real = SHIPPED
    for name in ("cross3d-16x32.safetensors", "SHA256SUMS", "catalog.json"):
        shutil.copy(real / name, folder / name)
    catalog = json.loads((folder / "catalog.json").read_text())
    catalog["weights"] = [e for e in catalog["weights"] if e["file"] == "cross3d-16x32.safetensors"] + list(entries)
    if edit is not None:
        edit(catalog)
    (folder / "catalog.json").write_text(json.dumps(catalog))
    monkeypatch.setattr(W, "SHIPPED_DIR", folder)
    return folder


def _tampered(path):
    """A copy of the paper weights with one tensor value changed: a valid file that is not shipped."""
    from safetensors.torch import load_file, save_file
    from safetensors import safe_open

    with safe_open(str(SHIPPED / "cross3d-16x32.safetensors"), framework="pt") as f:
        meta = f.metadata()
    state = load_file(str(SHIPPED / "cross3d-16x32.safetensors"))
    first = sorted(state)[0]
    state[first] = state[first] + 0.5
    path.parent.mkdir(parents=True, exist_ok=True)
    save_file(state, str(path), metadata=meta)
    return path


def _describe(capsys, weights):
    from doabench.cli.main import main

    capsys.readouterr()
    code = main(["describe", "--tracker", "cross3d:16x32", "--tracker-opt", f"weights={weights}"])
    return code, capsys.readouterr().err.strip()


@pytest.mark.parametrize("how", ["parent folder", "absolute path", "link out of the folder"])
def test_a_catalog_entry_cannot_point_outside_the_weights_folder(tmp_path, monkeypatch, capsys, how):
    """An edited catalog whose entry names a file outside the weights folder (``../``, an absolute
    path, a link in the folder to a file elsewhere) is refused in one line: the tampered file, which
    SHA256SUMS does not list, never runs under a shipped name."""
    outside = _tampered(tmp_path / "elsewhere" / "evil.safetensors")
    file = {"parent folder": "../elsewhere/evil.safetensors", "absolute path": str(outside),
            "link out of the folder": "evil.safetensors"}[how]
    folder = _weights_folder(tmp_path, monkeypatch, [{"tracker": "cross3d:16x32", "name": "evil", "file": file}])
    if how == "link out of the folder":
        (folder / "evil.safetensors").symlink_to(outside)
    code, err = _describe(capsys, "evil")
    assert code == 2 and len(err.splitlines()) == 1 and "catalog.json" in err, err
    assert ("symbolic link" if how.startswith("link") else "is not a .safetensors file name") in err


def test_a_link_in_the_weights_folder_given_by_path_is_refused(tmp_path, monkeypatch, capsys):
    """A file reached through the shipped folder is checked against SHA256SUMS however it is named:
    a link there to a tampered file is refused, a link elsewhere to a shipped file is checked."""
    import shutil

    folder = _weights_folder(tmp_path, monkeypatch)
    outside = _tampered(tmp_path / "elsewhere" / "cross3d-16x32-moving.safetensors")
    (folder / "cross3d-16x32-moving.safetensors").symlink_to(outside)
    code, err = _describe(capsys, folder / "cross3d-16x32-moving.safetensors")
    assert code == 2 and len(err.splitlines()) == 1 and "symbolic link" in err, err
    link = tmp_path / "mine" / "paper.safetensors"
    link.parent.mkdir()
    link.symlink_to(folder / "cross3d-16x32.safetensors")
    assert _describe(capsys, link)[0] == 0  # the shipped file, checked, through a link
    shutil.copy(outside, folder / "cross3d-16x32.safetensors")  # the shipped file replaced
    code, err = _describe(capsys, link)
    assert code == 2 and "does not match" in err, err


def test_catalog_names_are_unique_and_entries_complete(tmp_path, monkeypatch, capsys):
    """Two entries of one tracker and name are refused (not the last one silently), and so is an
    entry that lacks a key or has one of the wrong type: one line each, no traceback."""
    _tampered(tmp_path / "weights" / "cross3d-16x32-copy.safetensors")
    _weights_folder(tmp_path, monkeypatch, [{"tracker": "cross3d:16x32", "name": "paper",
                                             "file": "cross3d-16x32-copy.safetensors"}])
    code, err = _describe(capsys, "paper")
    assert code == 2 and len(err.splitlines()) == 1 and "has that tracker and name too" in err, err
    for broken, words in ([{"tracker": "cross3d:16x32", "name": "nofile"}, "lacks 'file'"],
                          [{"tracker": "cross3d:16x32", "name": 7, "file": "x.safetensors"}, "'name' is int"],
                          ["just text", "is not a mapping"]):
        import shutil

        shutil.rmtree(tmp_path / "weights")
        _weights_folder(tmp_path, monkeypatch, [broken])
        code, err = _describe(capsys, "paper")
        assert code == 2 and len(err.splitlines()) == 1 and words in err, err


@pytest.mark.parametrize("kind", ["fifo", "/dev/zero"])
def test_weights_that_are_not_a_regular_file_are_named_so(tmp_path, capsys, kind):
    import os

    path = tmp_path / "w.safetensors"
    if kind == "fifo":
        os.mkfifo(path)
    else:
        path = "/dev/zero"
    code, err = _describe(capsys, path)
    assert code == 2 and len(err.splitlines()) == 1 and "is not a regular file" in err, err
