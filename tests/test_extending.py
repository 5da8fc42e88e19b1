"""The plug-in points of docs/extending.md: a feature kind and a simulator backend from outside the
package, each the tested example the page shows; and the observation contract a tracker declares.

The plug-ins run in subprocesses: a registration is process-wide, and the other tests' messages
list the registered kinds."""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import doabench
from doabench.envs.env import DoaEnv
from doabench.errors import ConfigError
from doabench.features import ObservationSpec
from doabench.features.configs import KindConfig, MapConfig
from doabench.features.spec import ConfiguredKind
from doabench.features.kinds import feature_kind
from doabench.framing import FrameSpec

from conftest import ROOT

EXAMPLES = ROOT / "docs" / "examples"


def _run(code: str) -> str:
    done = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=ROOT, capture_output=True, text=True,
                          timeout=300, env={**os.environ, "PYTHONPATH": f"{EXAMPLES}:{ROOT}"})
    assert done.returncode == 0, done.stderr
    return done.stdout


@pytest.mark.parametrize("example", ["frame_energy.py", "srp_peaks.py", "free_field.py", "plane_wave.py"])
def test_the_page_shows_the_tested_examples(example):
    code = (EXAMPLES / example).read_text().rstrip()
    assert f"```python\n{code}\n```" in (ROOT / "docs" / "extending.md").read_text()


def test_a_plugin_feature_kind_is_an_observation_like_the_built_in_ones():
    out = _run('''
        import numpy as np, gymnasium
        from doabench.features import register_feature_kind
        from doabench.features.kinds import observation_kinds, storage_path
        from frame_energy import FRAME_ENERGY

        register_feature_kind(FRAME_ENERGY)
        assert "frame_energy" in observation_kinds() and storage_path("frame_energy") == "features/frame_energy"
        env = gymnasium.make("doabench/sim-demo-v2", features=("srp", "frame_energy"), resolution=(4, 8))
        assert env.observation_space["frame_energy"].shape == (12,)
        obs, _ = env.reset(options={"episode": 0})
        base = env.unwrapped
        episode, feats, _ = base.load_episode(0)
        spec = base.frame_spec
        frames = np.lib.stride_tricks.sliding_window_view(episode.audio, spec.window, axis=1)[:, ::spec.hop]
        expected = np.log10(np.maximum((frames.astype(np.float64) ** 2).mean(-1), 1e-12)).T  # (T, M)
        active = feats["vad"] == 1
        assert np.allclose(feats["frame_energy"][active], expected[active], atol=1e-4)
        assert not feats["frame_energy"][~active].any()  # silent frames zeroed, as every kind's
        print("ok", active.sum(), (~active).sum())
    ''')
    assert out.startswith("ok")


def test_a_misspelt_feature_kind_names_the_nearest():
    with pytest.raises(ConfigError, match="did you mean 'spectrogram'"):
        feature_kind("spectogram")
    with pytest.raises(ConfigError, match="taken"):
        doabench.features.register_feature_kind(feature_kind("srp"))


def test_a_plugin_simulator_backend_renders_free_field_physics_and_tasks():
    out = _run('''
        import numpy as np, gymnasium
        from doabench.acoustics.room import Room
        from doabench.acoustics.simulators import get_simulator, register_simulator
        from doabench.geometry import SPEED_OF_SOUND
        from free_field import FreeFieldSimulator

        register_simulator("free-field", FreeFieldSimulator)
        room = Room((6.0, 5.0, 3.0), 0.8, (1, 1, 1, 1, 1, 1))  # reverberant: the backend ignores the walls
        src, mics = np.array([[1.0, 1.0, 1.5]]), np.array([[4.0, 3.0, 1.2], [4.1, 3.0, 1.2]])
        click = np.zeros(16000)
        click[1000] = 1.0
        y = get_simulator("free-field").simulate(room, src, mics, click, 16000, seed=0)
        r = np.linalg.norm(mics - src, axis=1)
        assert np.all(np.abs(np.argmax(np.abs(y), axis=1) - 1000 - r / SPEED_OF_SOUND * 16000) <= 1)
        assert np.allclose((y.astype(np.float64) ** 2).sum(1), (1 / (4 * np.pi * r)) ** 2, rtol=0.05)
        env = gymnasium.make("doabench/sim-demo-v2", features=("srp",), resolution=(8, 16), backend="free-field")
        obs, info = env.reset(options={"episode": 0})
        print("ok", obs["srp"].shape)
    ''')
    assert out.startswith("ok (8, 16)")


def test_a_plugin_map_kind_is_on_the_grid_end_to_end(tmp_path):
    """The page's map kind: named with its grid, stored at its grid's path, observed with the grid's
    shape, computed from the shared maps, stored by make-dataset, read by a tracker declaring it."""
    out = _run(f'''
        import numpy as np
        import doabench
        from doabench.datasets import make_dataset
        from doabench.datasets.reader import DatasetFile
        from doabench.envs.env import DoaEnv
        from doabench.errors import ConfigError
        from doabench.features import FeatureKind, register_feature_kind
        from doabench.features.kinds import item_name, parse_item_name, storage_path
        from srp_peaks import SRP_PEAKS, PeakTracker

        register_feature_kind(SRP_PEAKS)
        assert item_name("srp_peaks", (4, 8)) == "srp_peaks:4x8" and parse_item_name("srp_peaks:4x8") == ("srp_peaks", (4, 8))
        assert storage_path("srp_peaks:4x8") == "features/srp_peaks_4x8"
        spec = doabench.ObservationSpec.of(("srp", "srp_peaks"), "4x8")
        assert str(spec) == "srp(grid=4x8, delays=nearest)+srp_peaks(grid=4x8, delays=nearest) @ 4096/3072@16000"
        assert spec.to_dict()["kinds"][1] == {{"kind": "srp_peaks", "grid": "4x8", "delays": "nearest"}}
        assert doabench.ObservationSpec.from_dict(spec.to_dict()) == spec == doabench.ObservationSpec.parse(str(spec))
        env = DoaEnv("sim-demo", spec)
        assert env.observation_space["srp_peaks"].shape == (4, 8)
        _, feats, _ = env.load_episode(0)
        assert feats["srp"].any() and np.allclose(feats["srp_peaks"], np.clip(feats["srp"], 0, None) ** 2, atol=1e-6)
        make_dataset("sim-demo", "{tmp_path}/peaks.h5", episodes=1, features="srp_peaks:4x8", progress=False)
        stored = DatasetFile("{tmp_path}/peaks.h5")
        assert list(stored.items) == ["srp_peaks:4x8"]
        assert np.array_equal(stored.read(0, ["srp_peaks:4x8"])["srp_peaks:4x8"], feats["srp_peaks"])
        doabench.register_tracker("srp-peaks")(PeakTracker)
        tracker = doabench.make_tracker("srp-peaks:4x8")
        assert tracker.observation_spec == doabench.ObservationSpec.of(("srp_peaks",), "4x8")
        assert tracker.resolution == (4, 8) and tracker.features == ("srp_peaks",)
        r = doabench.run("srp-peaks:4x8", "sim-demo", episodes=1, progress=False)
        assert np.isfinite(r["summary"]["rmsae_all"])
        try:  # a kind on the grid takes the grid's config
            register_feature_kind(FeatureKind("flat_map", lambda c: (1,), compute=lambda s: s.maps, on_grid=True))
        except ConfigError as exc:
            assert "takes MapConfig" in str(exc), exc
        else:
            raise AssertionError("a map kind without MapConfig was registered")
        print("ok")
    ''')
    assert out.startswith("ok")


def test_a_tracker_declares_what_it_reads_as_one_value():
    spec = doabench.make_tracker("srp-max:8x16").observation_spec
    assert spec == ObservationSpec(FrameSpec(), (ConfiguredKind("srp", MapConfig((8, 16), "nearest")),))
    assert spec == ObservationSpec.of(("srp",), "8x16")
    assert spec.with_delays("exact").delays == "exact" and spec.plan("nao").frame_shape("srp") == (8, 16)
    env = DoaEnv("sim-demo", spec)
    assert env.observations is spec and env.observation_space["srp"].shape == (8, 16)
    with pytest.raises(ConfigError, match="not both"):
        DoaEnv("sim-demo", spec, resolution=(4, 8))
    with pytest.raises(ConfigError, match="unknown delay mode"):
        ObservationSpec.of(("srp",), delays="fractional")
    with pytest.raises(ConfigError, match="unknown feature kind"):
        ObservationSpec.of(("srp", "spectogram"))
    with pytest.raises(ConfigError, match="takes a MapConfig"):
        ConfiguredKind("srp", KindConfig())
    with pytest.raises(ConfigError, match="share one grid"):
        ObservationSpec(FrameSpec(), (ConfiguredKind("srp", MapConfig((8, 16))), ConfiguredKind("srp_max", MapConfig((16, 32)))))


def test_a_tracker_class_reads_its_views_from_its_spec():
    """features, resolution and frame_spec are views of observation_spec; a class setting one of
    them to a value of its own is refused in one line (the environment would not read it)."""

    class Reads(doabench.Tracker):
        observation_spec = ObservationSpec.of(("srp", "gcc"), "4x8", FrameSpec(1024))

    reads = Reads()
    assert (reads.features, reads.resolution, reads.frame_spec) == (("srp", "gcc"), (4, 8), FrameSpec(1024))
    with pytest.raises(ConfigError, match="sets features: declare what it reads"):
        type("Old", (doabench.Tracker,), {"features": ("gcc",)})
    with pytest.raises(ConfigError, match="observation_spec must be a doabench.ObservationSpec"):
        type("Bad", (doabench.Tracker,), {"observation_spec": ("gcc",)})


def test_the_spec_has_one_text_and_one_stored_form():
    """Each configured kind round-trips through its text and stored forms, and so does the spec;
    from_dict reads exactly what to_dict writes (anything else: one line)."""
    spec = ObservationSpec.of(("srp", "srp_max", "gcc", "audio"), "8x16", FrameSpec(2048), "exact")
    assert str(spec) == ("srp(grid=8x16, delays=exact)+srp_max(grid=8x16, delays=exact)+gcc+audio "
                         "@ 2048/1536@16000")
    assert spec.to_dict() == {"frames": {"window": 2048, "hop": 1536, "fs": 16000},
                              "kinds": [{"kind": "srp", "grid": "8x16", "delays": "exact"},
                                        {"kind": "srp_max", "grid": "8x16", "delays": "exact"},
                                        {"kind": "gcc"}, {"kind": "audio"}]}
    assert ObservationSpec.parse(str(spec)) == spec == ObservationSpec.from_dict(spec.to_dict())
    assert (spec.kind_names, spec.resolution, spec.delays) == (("srp", "srp_max", "gcc", "audio"), (8, 16), "exact")
    assert hash(spec) == hash(ObservationSpec.of(("srp", "srp_max", "gcc", "audio"), (8, 16), FrameSpec(2048), "exact"))
    own = ObservationSpec.of(("spectrogram",), None, FrameSpec(), None, FrameSpec(512))
    assert own.to_dict()["kinds"] == [{"kind": "spectrogram", "frames": {"window": 512, "hop": 384, "fs": 16000}}]
    assert str(own) == "spectrogram(frames=512/384@16000) @ 4096/3072@16000"
    assert ObservationSpec.parse(str(own)) == own == ObservationSpec.from_dict(own.to_dict())
    assert own.resolution is None and own.delays is None and own.with_delays("exact") == own
    same = ObservationSpec.of(("spectrogram",), None, FrameSpec(), None, FrameSpec())
    assert same.to_dict()["kinds"] == [{"kind": "spectrogram", "frames": None}] and not same.separate_spectrogram_grid
    assert ConfiguredKind.parse("srp(grid=4x8)") == ConfiguredKind("srp", MapConfig((4, 8), "nearest"))
    frames = {"window": 4096, "hop": 3072, "fs": 16000}
    for bad, match in [({"kinds": ["srp"]}, "not a stored observation spec"),
                       ({"frames": frames, "kinds": ["srp"]}, "a stored kind is"),
                       ({"frames": frames, "kinds": [{"kind": "srp", "grid": "8x16"}]}, "missing: delays"),
                       ({"frames": frames, "kinds": [{"kind": "gcc", "grid": "8x16"}]}, "unknown: grid"),
                       ({"frames": {"window": 4096}, "kinds": []}, "frames must be"),
                       ({"frames": frames, "kinds": [{"kind": "mfcc"}]}, "unknown feature kind")]:
        with pytest.raises(ConfigError, match=match):
            ObservationSpec.from_dict(bad)
    with pytest.raises(ConfigError, match="is not KINDS @"):
        ObservationSpec.parse("srp(grid=8x16)")


def test_the_environment_refuses_a_spectrogram_on_its_own_frames():
    """A tracker whose spectrogram has its own frame grid cannot be given it by the environment
    (another number of frames): one line, rather than observations it was not trained on."""
    spec = ObservationSpec.of(("spectrogram",), frame_spec=FrameSpec(), spectrogram_frame_spec=FrameSpec(window=512))
    assert spec.separate_spectrogram_grid
    with pytest.raises(ConfigError, match="on frames of its own"):
        DoaEnv("sim-demo", spec)
    same = ObservationSpec.of(("spectrogram",), spectrogram_frame_spec=FrameSpec())
    assert same.spectrogram_frame_spec is None and np.isfinite(DoaEnv("sim-demo", same).n_episodes)


def test_task_kinds_declare_their_options_and_scoring_policy():
    """Each built-in kind declares its run-time options as a dataclass and its headline; the CLI's
    corpus flags are built from those dataclasses' fields; a kind is given only its own."""
    import argparse
    import dataclasses

    from doabench.cli.common import add_corpus_options
    from doabench.envs.sources import available_task_kinds, kind_options, task_kind

    policies = {}
    for kind in ("simulated", "locata", "dataset"):
        factory = task_kind(kind)
        assert dataclasses.is_dataclass(factory.Options), kind
        policies[kind] = getattr(factory, "headline", None)
    assert policies == {"simulated": "pooled", "locata": "recording_mean", "dataset": None}
    taken = set().union(*(kind_options(task_kind(k)) for k in available_task_kinds()))
    parser = argparse.ArgumentParser()
    add_corpus_options(parser)
    flags = {a.dest for a in parser._actions if a.dest != "help"}
    assert flags <= taken, flags - taken
    assert flags == {"librispeech", "backend", "device", "locata_root", "split", "vad"}
    assert parser.parse_args(["--split", "eval"]).split == "eval" and parser.parse_args([]).backend == "builtin"
    assert kind_options(task_kind("simulated")) == {"librispeech", "backend", "device", "scene_overrides"}


def test_a_plugin_kind_without_declared_options_gets_every_option():
    """A kind whose factory is ``f(spec, **options)`` and declares no ``Options`` is given every option
    that was given (not None), as before kinds declared theirs."""
    out = _run('''
        import dataclasses
        from doabench.envs.registry import get_task_spec
        from doabench.envs.sources import make_episode_source, register_task_kind, task_kind

        seen = {}

        def factory(spec, **options):
            seen.update(options)
            return task_kind("simulated")(dataclasses.replace(spec, kind="simulated"))

        register_task_kind("test-any-options", factory)
        spec = dataclasses.replace(get_task_spec("sim-demo"), kind="test-any-options")
        assert len(make_episode_source(spec, librispeech="/somewhere", locata_root=None)) == 4
        assert seen == {"librispeech": "/somewhere"}, seen
        print("ok")
    ''')
    assert out.startswith("ok")


def test_a_plugin_task_kind_runs_and_a_plane_wave_is_found_where_it_comes_from():
    out = _run('''
        import doabench
        from doabench.errors import ConfigError
        from plane_wave import PlaneWaveEpisodes

        doabench.register_task_kind("plane-wave", PlaneWaveEpisodes)
        doabench.register_task({"id": "plane-check", "version": 1, "kind": "plane-wave", "array": "nao",
                                "episodes": 3, "base_seed": 7, "plane_wave": {"duration_s": 2.0}})
        r = doabench.run("srp-max:32x64", "plane-check", progress=False, snr_db=20)
        assert r["summary"]["headline"]["aggregate"] == "pooled"
        assert r["summary"]["rmsae_all"] < 4.0, r["summary"]["rmsae_all"]  # within the 5.6-degree grid
        try:
            doabench.run("srp-max:32x64", "plane-check", progress=False, snr_dB=20)
        except ConfigError as exc:
            assert "did you mean 'snr_db'" in str(exc), exc
        else:
            raise AssertionError("a misspelt option was accepted")
        print("ok", round(r["summary"]["rmsae_all"], 2))
    ''')
    assert out.startswith("ok")


def test_the_observation_contract_is_one_stored_value(tmp_path):
    """A tracker declares an ObservationSpec; results, weights and ONNX files store its to_dict(),
    and each file alone gives it back."""
    from doabench_baselines.catalog import find_weights
    from doabench_baselines.weights import WeightsFile, read_metadata

    tracker = doabench.make_tracker("cross3d:16x32", weights="moving")
    spec = tracker.observation_spec
    assert ObservationSpec.from_dict(spec.to_dict()) == spec
    assert doabench.ObservationSpec is ObservationSpec
    # a weights file: the stored spec, or for a file older than it, the same read from its features
    old = find_weights("cross3d", (16, 32), "moving")
    assert old.observations == spec
    path = tracker.save_weights(tmp_path / "w.safetensors", {"observations": spec.with_delays("exact").to_dict()})
    saved = WeightsFile(path, read_metadata(path))
    assert saved.metadata["observations"] == spec.with_delays("exact").to_dict()
    assert saved.observations == spec.with_delays("exact") and saved.delay_mode == "exact"
    # a tracker on those weights declares exact delays, and the trainer trains it on them
    from doabench.training.protocol import training_observations

    exact = doabench.make_tracker("cross3d:16x32", weights=str(path))
    assert exact.observation_spec == spec.with_delays("exact")
    assert training_observations(exact) == spec.with_delays("exact")
    # the environment observes through the same value
    env = DoaEnv("sim-demo", spec)
    assert env.observations == spec
    with pytest.raises(ConfigError, match="not a stored observation spec"):
        ObservationSpec.from_dict({"kinds": ["srp"]})
