"""The neural trackers through doabench's public API: registry, describe, step/track, errors, a run."""
from __future__ import annotations

import ast
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

import doabench
from doabench.errors import ConfigError, TrackerError
from doabench_baselines.trackers.cross3d import Cross3DTracker

ROOT = Path(__file__).resolve().parents[1]
IDS = ("cross3d", "gcc-cnn1d", "max-cnn1d", "spec-cnn2d", "seldnet")



def _make(text, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # untrained-model warning, tested separately
        return doabench.make_tracker(text, weights="random", **options)


def _episode(tracker, n, seed=0):
    rng = np.random.default_rng(seed)
    ep = {"vad": np.ones(n)}
    if "srp" in tracker.features:
        ep["srp"] = rng.standard_normal((n,) + tracker.resolution).astype(np.float32)
    if "srp_max" in tracker.features:
        ep["srp_max"] = rng.random((n, 2)).astype(np.float32)
    if "gcc" in tracker.features:
        ep["gcc"] = rng.standard_normal((n, 66, 13)).astype(np.float32)
    for kind in ("spectrogram", "spectrogram_ipd"):
        if kind in tracker.features:
            ep[kind] = rng.random((n, 24, tracker.frame_spec.window // 2)).astype(np.float32)
    return ep


def test_registered_through_the_public_registry():
    available = doabench.available_trackers()
    for name in IDS:
        assert issubclass(available[name], doabench.Tracker)
    assert isinstance(_make("cross3d:4x8"), Cross3DTracker)


def test_baselines_import_only_the_public_api():
    """baselines/ is a plugin: from doabench it may import the package itself, its errors and the
    public trackers package (``parse_resolution`` for tracker specs) only."""
    allowed = {"doabench", "doabench.errors", "doabench.trackers"}
    for path in sorted((ROOT / "baselines").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names = [node.module]
            for name in names:
                if name.split(".")[0] == "doabench":
                    assert name in allowed, f"{path.name} imports {name}"


@pytest.mark.parametrize("text,parameters,rf,resolution", [
    ("cross3d:4x8", 526_372, 29, "4x8"), ("cross3d:8x16", 946_340, 33, "8x16"),
    ("cross3d:16x32", 1_693_988, 37, "16x32"), ("cross3d:32x64", 5_626_148, 37, "32x64"),
    ("gcc-cnn1d", 11_282_436, 37, None), ("max-cnn1d", 6_899_716, 37, "64x128"),
    ("spec-cnn2d", 1_882_372, 37, None), ("seldnet", 104_643, None, None),
])
def test_describe(text, parameters, rf, resolution):
    d = _make(text).describe()
    assert (d["parameters"], d["receptive_field_frames"], d["resolution"]) == (parameters, rf, resolution)
    assert d["trained"] is False and d["weights_hash"] is None and d["weights"] is None
    assert d["name"] == text.split(":")[0]


def test_cross3d_describe_at_64x128():
    d = _make("cross3d:64x128").describe()
    assert (d["parameters"], d["receptive_field_frames"], d["receptive_field_s"]) == (21_354_788, 37, 7.168)


def test_untrained_tracker_warns_unless_random_was_asked_for():
    with pytest.warns(UserWarning, match="no trained weights for 12x24 maps"):  # none shipped at 12x24
        t = Cross3DTracker("12x24")
    assert not t.trained and not t.allow_untrained
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        t = Cross3DTracker("4x8", weights="random")
    assert not t.trained and t.allow_untrained


@pytest.mark.parametrize("text", ["cross3d:4x8", "cross3d:8x16", "gcc-cnn1d", "max-cnn1d"])
def test_step_equals_track_and_returns_unit_vectors(text):
    tracker = _make(text)
    nao = doabench.get_array("nao")
    ep = _episode(tracker, 40)
    tracker.reset(nao, frame_spec=tracker.frame_spec)
    stepped = np.stack([tracker.step({k: v[t] for k, v in ep.items()}) for t in range(40)])
    tracker.reset(nao)
    tracked = tracker.track(ep)
    assert tracked.shape == (40, 3)
    np.testing.assert_allclose(np.linalg.norm(stepped, axis=1), 1.0, atol=1e-9)
    np.testing.assert_allclose(stepped, tracked, atol=1e-5)


def test_seldnet_is_offline():
    tracker = _make("seldnet")
    assert not tracker.causal and tracker.frame_spec.to_dict() == {"window": 512, "hop": 384, "fs": 16000}
    tracker.reset(doabench.get_array("nao"))
    ep = _episode(tracker, 30)
    out = tracker.track(ep)
    assert out.shape == (30, 3)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-9)
    with pytest.raises(NotImplementedError):
        tracker.step({k: v[0] for k, v in ep.items()})


def test_a_zero_network_output_keeps_the_previous_direction():
    tracker = _make("max-cnn1d")
    tracker.reset(doabench.get_array("nao"))
    first = tracker.direction_from_output(np.array([0.0, 2.0, 0.0]))
    assert np.allclose(first, [0, 1, 0])
    assert np.allclose(tracker.direction_from_output(np.zeros(3)), [0, 1, 0])
    with pytest.raises(TrackerError):  # a NaN output is never turned into a held estimate
        tracker.direction_from_output(np.array([np.nan, 0, 0]))


def test_user_mistakes_are_config_errors():
    with pytest.raises(ConfigError, match="takes no map resolution"):
        _make("gcc-cnn1d:16x32")
    with pytest.raises(ConfigError, match="not of the form"):
        _make("cross3d:sixteen")
    with pytest.raises(ConfigError, match="bad options"):
        _make("cross3d:4x8", colour="red")
    if not torch.cuda.is_available():
        with pytest.raises(ConfigError, match="CUDA is not available"):
            _make("cross3d:4x8", device="cuda")
    tracker = _make("cross3d:4x8")
    tracker.reset(doabench.get_array("nao"))
    with pytest.raises(ConfigError, match="expects 4x8 maps, got 8x16"):
        tracker.step({"srp": np.zeros((8, 16), np.float32), "srp_max": np.zeros(2, np.float32), "vad": 1})
    with pytest.raises(ConfigError, match="needs frames"):
        tracker.reset(doabench.get_array("nao"), frame_spec=doabench.FrameSpec(window=2048))


def test_array_the_input_layer_cannot_take_is_a_config_error():
    three = doabench.MicArray("three", np.eye(3) * 0.05)
    for text in ("gcc-cnn1d", "spec-cnn2d"):
        with pytest.raises(ConfigError, match="array=NAME_OR_FILE"):
            _make(text).reset(three)


def test_gcc_cnn1d_input_width_follows_the_array_option(tmp_path):
    path = tmp_path / "tri.json"
    path.write_text('{"name": "tri", "positions": [[0.05, 0, 0], [-0.05, 0, 0], [0, 0.05, 0]]}')
    tracker = _make("gcc-cnn1d", array=str(path))
    lags = 2 * doabench.load_array_file(path).max_lag(16000) + 1
    assert tracker.model.in_channels == 3 * lags
    tracker.reset(doabench.load_array_file(path))


def test_runs_a_task_end_to_end():
    scene = {"duration_s": 3.0, "n_points": 24}
    for text in ("cross3d:4x8", "seldnet"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            results = doabench.run(text, "sim-demo", episodes=1, progress=False, scene_overrides=scene,
                                   tracker_options={"weights": "random"})
        assert results["tracker"]["trained"] is False
        assert np.isfinite(results["summary"]["rmsae_all"])


@pytest.mark.parametrize("text", ["cross3d:4x8", "gcc-cnn1d", "max-cnn1d", "spec-cnn2d", "seldnet"])
def test_training_protocol(text, tmp_path):
    """What `doabench train` uses: network, network_input on batched features, save_weights."""
    from doabench.training.protocol import check_trainable

    tracker = check_trainable(_make(text), text)
    ep = _episode(tracker, 6)
    batch = {k: torch.as_tensor(np.stack([v, v[::-1].copy()])) for k, v in ep.items()}  # (2, 6, ...)
    y = tracker.network(tracker.network_input(batch))
    assert y.shape == (2, 6, 3)
    path = tracker.save_weights(tmp_path / "w.safetensors", {"array": "nao", "training": {"epochs_completed": 1},
                                                              "feature_settings": {"delays": "nearest"}})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        loaded = doabench.make_tracker(text, weights=str(path))
    assert loaded.describe()["training"] == {"epochs_completed": 1}


@pytest.mark.parametrize("text", ["spec-cnn2d", "seldnet"])
def test_phase_option_reads_relative_phases_and_travels_with_the_weights(text, tmp_path):
    """phase=relative reads the spectrogram_ipd kind; weights trained on it carry it (phase=auto
    reads it back), and weights of one phase are refused with the other, in one line."""
    tracker = _make(text, phase="relative")
    assert tracker.phase == "relative" and tracker.features == ("spectrogram_ipd",)
    assert _make(text).phase == "absolute" and _make(text).features == ("spectrogram",)
    ep = _episode(tracker, 4)
    batch = {k: torch.as_tensor(v[None]) for k, v in ep.items()}
    assert tracker.network(tracker.network_input(batch)).shape == (1, 4, 3)
    path = tracker.save_weights(tmp_path / "w.safetensors", {"array": "nao", "training": {"epochs_completed": 1}})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        loaded = doabench.make_tracker(text, weights=str(path))
        assert loaded.phase == "relative" and loaded.features == ("spectrogram_ipd",)
        assert doabench.make_tracker(text, weights=str(path), phase="relative").phase == "relative"
    with pytest.raises(ConfigError, match="not on the kind .* phase=absolute \\(spectrogram\\)"):
        doabench.make_tracker(text, weights=str(path), phase="absolute")
    with pytest.raises(ConfigError, match="phase must be auto, absolute or relative, got 'ipd'"):
        _make(text, phase="ipd")
    with pytest.raises(ConfigError, match="its weights read other observations"):  # shipped: absolute phases
        tracker.warm_start_from(doabench.make_tracker(text))


def test_relative_phase_tracker_runs_a_task():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        results = doabench.run("seldnet", "sim-demo", episodes=1, progress=False,
                               scene_overrides={"duration_s": 3.0, "n_points": 24},
                               tracker_options={"weights": "random", "phase": "relative"})
    assert results["tracker"]["features"] == ["spectrogram_ipd"] and results["tracker"]["options"]["phase"] == "relative"
    assert np.isfinite(results["summary"]["rmsae_all"])


def test_hold_in_silences_repeats_the_last_informed_frame():
    d = np.arange(10, dtype=float)[:, None] * np.ones((1, 3))
    vad = np.array([0, 1, 0, 0, 0, 0, 1, 0, 0, 0], bool)
    out = doabench.hold_in_silences(d, vad, 2)
    # frame 0: no voice yet (as is); 2: one silent frame (as is); 3-5 hold frame 2; 6 voiced; 7 as is; 8-9 hold 7
    assert out[:, 0].tolist() == [0, 1, 2, 2, 2, 2, 6, 7, 7, 7]
    assert np.array_equal(doabench.hold_in_silences(d, np.zeros(10, bool), 2), d)


@pytest.mark.parametrize("text", ["cross3d:4x8", "max-cnn1d"])
def test_hold_beyond_half_the_receptive_field_in_step_and_track(text):
    tracker = _make(text)
    rf = tracker.receptive_field_frames
    assert tracker.hold_frames == rf // 2 and tracker.describe()["hold_frames"] == rf // 2
    nao = doabench.get_array("nao")
    n = 3 * rf
    ep = _episode(tracker, n, seed=3)
    ep["vad"] = np.r_[np.zeros(3), np.ones(rf), np.zeros(n - rf - 3)]
    tracker.reset(nao)
    stepped = np.stack([tracker.step({k: v[t] for k, v in ep.items()}) for t in range(n)])
    tracker.reset(nao)
    tracked = tracker.track(ep)
    np.testing.assert_allclose(stepped, tracked, atol=1e-5)
    start = 3 + rf - 1 + rf // 2  # the first held frame: hold frames after the last voiced one
    assert np.allclose(tracked[start:], tracked[start - 1])
    assert not np.allclose(tracked[start - 1], tracked[start - 2])  # the model still moves before
    off = _make(text, hold="off")
    off.reset(nao)
    free = off.track(ep)
    assert off.hold_frames is None and np.allclose(free[:start], tracked[:start])
    assert not np.allclose(free[start:], tracked[start - 1])
    assert _make(text, hold=5).hold_frames == 5
    with pytest.raises(ConfigError, match="hold must be"):
        _make(text, hold="sometimes")
