"""ObservationPlan: the one list of kinds, names and dataset paths, spaces, and compute() equal to the
FeatureExtractor; DoaEnv and make-dataset's EpisodeComputer compute through it."""
import dataclasses

import numpy as np
import pytest
import torch
from gymnasium import spaces

import doabench
from doabench.arrays import get_array
from doabench.datasets import schema
from doabench.datasets.compute import EpisodeComputer, requests_plan
from doabench.envs import env as env_module
from doabench.envs.env import DoaEnv
from doabench.errors import ConfigError
from doabench.features import FeatureExtractor, ObservationPlan, transforms
from doabench.features.kinds import (
    BUILTIN_KINDS,
    EXTRACTOR_KINDS,
    FRAMED_KINDS,
    OBSERVATION_KINDS,
    item_name,
    parse_item_name,
    storage_path,
)
from doabench.features.plan import framed_audio
from doabench.features.spec import ObservationSpec
from doabench.framing import FrameSpec


SPEC = FrameSpec(1024)


def _recording(seed=0, n_mics=12, samples=1024 + 768 * 9):
    rng = np.random.default_rng(seed)
    audio = (0.1 * rng.standard_normal((n_mics, samples))).astype(np.float32)
    vad = np.ones(samples, bool)
    vad[: samples // 3] = False  # silent frames must come out zeroed, as the extractor's
    return audio, vad


def test_one_kind_registry_everywhere():
    """Every layer reads the kinds from the one registry: no module keeps its own list under another name."""
    assert not hasattr(env_module, "FEATURE_KINDS") and not hasattr(transforms, "KINDS")
    assert not hasattr(schema, "KINDS") and not hasattr(schema, "HALF_KINDS")
    assert set(EXTRACTOR_KINDS) | set(FRAMED_KINDS) == set(OBSERVATION_KINDS)
    assert tuple(k.name for k in BUILTIN_KINDS if k.half) == ("srp", "gcc", "spectrogram", "spectrogram_ipd")
    assert doabench.ObservationPlan is ObservationPlan


@pytest.mark.parametrize("name, parsed, path", [
    ("srp:16x32", ("srp", (16, 32)), "features/srp_16x32"),
    ("srp_max:8x16", ("srp_max", (8, 16)), "features/srp_max_8x16"),
    ("gcc", ("gcc", None), "features/gcc"),
    ("spectrogram", ("spectrogram", None), "features/spectrogram"),
    ("spectrogram_ipd", ("spectrogram_ipd", None), "features/spectrogram_ipd"),
    ("audio", ("audio", None), "audio"),
])
def test_names_round_trip_and_paths(name, parsed, path):
    assert parse_item_name(name) == parsed
    assert item_name(*parsed) == name
    assert storage_path(name) == path


def test_bad_names():
    with pytest.raises(ConfigError, match=r"unknown feature kind\(s\) \['mfcc'\]; choose from srp, srp_max"):
        parse_item_name("mfcc")
    with pytest.raises(ConfigError, match="takes no resolution"):
        parse_item_name("gcc:4x8")
    with pytest.raises(ConfigError, match="not of the form"):
        parse_item_name("srp:big")


def test_storage_paths_equal_the_schema_layout():
    """The HDF5 layout of docs/hdf5-schema.md, as FeatureRequest.stored() gave it before the plan."""
    requests = schema.parse_features("srp:4x8,srp:16x32,gcc,spectrogram,audio")
    assert {n: p for r in requests for n, p in r.stored().items()} == {
        "srp:4x8": "features/srp_4x8", "srp_max:4x8": "features/srp_max_4x8",
        "srp:16x32": "features/srp_16x32", "srp_max:16x32": "features/srp_max_16x32",
        "gcc": "features/gcc", "spectrogram": "features/spectrogram", "audio": "audio"}
    plan = requests_plan(requests, get_array("nao"), SPEC)
    assert plan.names() == ["srp:4x8", "srp_max:4x8", "gcc", "spectrogram", "srp:16x32", "srp_max:16x32"]
    assert plan.passes() == [(("srp", "srp_max", "gcc", "spectrogram"), (4, 8)), (("srp", "srp_max"), (16, 32))]
    assert requests_plan(schema.parse_features("audio"), get_array("nao"), SPEC) is None


def test_spaces_match_what_the_environment_declared():
    array = get_array("nao")
    plan = ObservationSpec.of(OBSERVATION_KINDS, (8, 16), SPEC).plan(array)
    assert isinstance(plan, ObservationPlan) and plan.spec == ObservationSpec.of(OBSERVATION_KINDS, "8x16", SPEC)
    lags = 2 * array.max_lag(SPEC.fs) + 1
    want = {
        "srp": spaces.Box(-np.inf, 1.0, (8, 16), np.float32),
        "srp_max": spaces.Box(0.0, 1.0, (2,), np.float32),
        "gcc": spaces.Box(-1.0, 1.0, (len(array.pairs), lags), np.float32),
        "spectrogram": spaces.Box(-1.0, 1.0, (2 * array.n_mics, SPEC.window // 2), np.float32),
        "spectrogram_ipd": spaces.Box(-1.0, 1.0, (2 * array.n_mics, SPEC.window // 2), np.float32),
        "audio": spaces.Box(-np.inf, np.inf, (array.n_mics, SPEC.window), np.float32),
        "vad": spaces.Discrete(2),
    }
    assert plan.observation_space() == spaces.Dict(want)
    assert list(ObservationSpec.of(("gcc", "srp"), None, SPEC).plan(array).observation_space().spaces) == [
        "gcc", "srp", "vad"]


def test_compute_equals_the_extractor():
    array = get_array("nao")
    audio, vad = _recording()
    plan = ObservationSpec.of(("srp", "srp_max", "gcc", "spectrogram", "audio"), None, SPEC).plan(array, ((4, 8), (8, 16)))
    items = plan.compute(audio, vad)
    first = FeatureExtractor(array, kinds=EXTRACTOR_KINDS, resolution=(4, 8), frame_spec=SPEC)(audio, vad)
    second = FeatureExtractor(array, kinds=("srp", "srp_max"), resolution=(8, 16), frame_spec=SPEC)(audio, vad)
    for name, ref in [("srp:4x8", first["srp"]), ("srp_max:4x8", first["srp_max"]), ("gcc", first["gcc"]),
                      ("spectrogram", first["spectrogram"]), ("srp:8x16", second["srp"]),
                      ("srp_max:8x16", second["srp_max"])]:
        np.testing.assert_array_equal(items[name], ref.numpy(), err_msg=name)
    np.testing.assert_array_equal(items["vad"], first["vad"].numpy().astype(np.int64))
    assert items["vad"].dtype == np.int64 and not items["vad"][:2].any()
    np.testing.assert_array_equal(items["audio"], framed_audio(audio, SPEC))
    assert items["audio"].shape == (len(items["vad"]), array.n_mics, SPEC.window)
    np.testing.assert_array_equal(items["audio"][3, :, 5], audio[:, 3 * SPEC.hop + 5])
    assert set(items) == set(plan.names()) | {"vad"}
    with pytest.raises(ValueError, match="one SRP grid"):
        plan.observations(audio, vad)


def test_audio_only_still_frames_the_vad():
    """Framed audio needs no extractor, but the extractor still gives the frame VAD."""
    audio, vad = _recording()
    plan = ObservationSpec.of(("audio",), None, SPEC).plan("nao")
    assert plan.extractor_kinds == ("srp_max",)
    obs = plan.observations(audio, vad)
    assert obs["audio"].shape[1:] == (12, SPEC.window) and len(obs["vad"]) == len(obs["audio"])


def test_environment_and_dataset_computer_use_the_plan(monkeypatch):
    env = DoaEnv("sim-demo", features=("srp", "gcc"), resolution="4x8")
    assert isinstance(env.plan, ObservationPlan)
    assert env.plan.kinds == ("srp", "gcc") and env.plan.resolution == (4, 8)
    assert env.observation_space == env.plan.observation_space()
    computer = EpisodeComputer(doabench.get_task_spec("sim-demo"), schema.parse_features("srp:4x8,gcc"))
    assert isinstance(computer.plan, ObservationPlan)
    calls = []
    original = ObservationPlan.compute

    def spy(self, *args, **kwargs):
        calls.append(self)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(ObservationPlan, "compute", spy)
    audio, vad = _recording(samples=4096 + 3072 * 2)
    stored = computer.features(audio, vad, computer.array)
    assert calls == [computer.plan]
    assert list(stored) == ["features/srp_4x8", "features/srp_max_4x8", "features/gcc"]


def test_unknown_environment_kind_message():
    with pytest.raises(ConfigError, match=r"unknown feature kind\(s\) \['mfcc'\]; choose from srp, srp_max, gcc, "
                                          r"spectrogram, spectrogram_ipd, audio"):
        DoaEnv("sim-demo", features=("srp", "mfcc"))


def test_each_kind_computes_itself_from_one_shared_stft(monkeypatch):
    """The extractor asks each kind's own ``compute`` (no branching on names): every computed kind
    declares one, a pass takes one STFT on each frame grid whatever the kinds, and a kind on its own
    frames (the spectrogram) is computed on the second grid with its VAD."""
    from doabench.features import functional as F
    from doabench.features.kinds import BUILTIN_KINDS, FEATURE_KINDS, FeatureKind

    assert all((k.compute is None) == k.framed for k in BUILTIN_KINDS)

    calls = []
    real = F.stft_frames
    monkeypatch.setattr(F, "stft_frames", lambda x, window, hop: calls.append(window) or real(x, window, hop))
    audio, vad = _recording()
    one_grid = FeatureExtractor("nao", ("srp", "srp_max", "gcc", "spectrogram"), (4, 8), frame_spec=SPEC)
    out = one_grid(audio, vad)
    assert calls == [SPEC.window] and set(out) == {"srp", "srp_max", "gcc", "spectrogram", "vad"}
    calls.clear()
    own = FrameSpec(512)
    two_grids = FeatureExtractor("nao", ("gcc", "spectrogram"), frame_spec=SPEC, spectrogram_frame_spec=own)
    out = two_grids(audio, vad)
    assert sorted(calls) == [own.window, SPEC.window]
    assert out["spectrogram"].shape[0] == own.n_frames(audio.shape[1]) == out["spectrogram_vad"].shape[0]
    assert torch.equal(out["spectrogram"], F.zero_silent(F.spectrogram_features(real(
        torch.from_numpy(audio)[None], own.window, own.hop)), out["spectrogram_vad"][None])[0])

    # a plug-in kind reading a shared stage gets the same tensor the built-in kind returns
    monkeypatch.setattr(FEATURE_KINDS, "_entries", dict(FEATURE_KINDS.registered()))  # registered for this test only
    # and a built-in kind is what its own declaration computes, not a branch on its name
    gcc = FEATURE_KINDS.get("gcc")
    FEATURE_KINDS._entries["gcc"] = dataclasses.replace(gcc, compute=lambda s: torch.full_like(s.gcc, 0.5))
    out = FeatureExtractor("nao", ("gcc",), frame_spec=SPEC)(audio, vad)
    assert out["vad"].any() and set(out["gcc"][out["vad"]].unique().tolist()) == {0.5}
    FEATURE_KINDS._entries["gcc"] = gcc
    FEATURE_KINDS.register("gcc_copy", FeatureKind("gcc_copy", FEATURE_KINDS.get("gcc").frame_shape, compute=lambda s: s.gcc,
                                                   stages=("gcc",)))
    out = FeatureExtractor("nao", ("gcc_copy",), frame_spec=SPEC)(audio, vad)
    assert torch.equal(out["gcc_copy"], FeatureExtractor("nao", ("gcc",), frame_spec=SPEC)(audio, vad)["gcc"])
    with pytest.raises(ConfigError, match="unknown stage"):
        FEATURE_KINDS.register("bad", FeatureKind("bad", lambda c: (1,), compute=lambda s: s.maps, stages=("maps",)))
    with pytest.raises(ConfigError, match="without declaring it"):  # reads the maps, declares no stage
        FEATURE_KINDS.register("sneaky", FeatureKind("sneaky", lambda c: (4, 8), compute=lambda s: s.maps))
        FeatureExtractor("nao", ("sneaky",), frame_spec=SPEC)(audio, vad)
