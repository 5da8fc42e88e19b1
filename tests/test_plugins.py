"""One registry type with one set of rules behind every plug-in point (doabench/plugins.py): trackers,
task kinds, task-id prefixes, feature kinds and room simulators. doabench's own entries are declared
in its pyproject.toml the way a plug-in's are, and a real installed plug-in (a package with its
``.dist-info`` in a temporary folder) is found, loaded lazily, and refused in one line when broken."""
from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap

import pytest

import doabench
from doabench.acoustics import simulators
from doabench.envs import registry as task_registry
from doabench.envs import sources
from doabench.errors import ConfigError, NotFoundError
from doabench.features import kinds
from doabench.plugins import Registry
from doabench.trackers import registry as tracker_registry

from conftest import ROOT

REGISTRIES = {
    "doabench.trackers": tracker_registry.TRACKERS,
    "doabench.task_kinds": sources.TASK_KINDS,
    "doabench.task_prefixes": task_registry.TASK_PREFIXES,
    "doabench.feature_kinds": kinds.FEATURE_KINDS,
    "doabench.simulators": simulators.SIMULATORS,
}


def _entry_points() -> dict[str, dict[str, str]]:
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["entry-points"]


def test_every_plug_in_point_is_one_registry_of_its_group():
    for group, registry in REGISTRIES.items():
        assert isinstance(registry, Registry) and registry.group == group
    assert set(_entry_points()) <= set(REGISTRIES)


def test_built_in_trackers_are_declared_like_plug_ins():
    """Every ``register_tracker`` id in doabench and baselines/ has its entry point: no tracker is
    found through a hard-coded import list."""
    declared = _entry_points()["doabench.trackers"]
    decorated = {}
    for path in [*(ROOT / "doabench").rglob("*.py"), *(ROOT / "baselines").rglob("*.py")]:
        text = path.read_text(encoding="utf-8")
        for name, cls in re.findall(r'register_tracker\("([^"]+)"\)\s*\nclass (\w+)', text):
            module = ".".join(path.relative_to(ROOT).with_suffix("").parts).replace("baselines", "doabench_baselines", 1)
            decorated[name] = f"{module}:{cls}"
    assert decorated and decorated == declared
    assert "_load_builtins" not in (ROOT / "doabench" / "trackers" / "registry.py").read_text()


def test_the_rules_are_the_same_for_every_registry():
    reg: Registry[object] = Registry("gadget", "doabench.no_such_group")

    class Alpha:
        pass

    class Beta:
        pass

    assert reg.register("alpha", Alpha) is Alpha and reg.register("alpha", Alpha) is Alpha  # again: fine
    with pytest.raises(ConfigError, match=r"gadget 'alpha' is already registered by .*Alpha"):
        reg.register("alpha", Beta)
    assert reg.get("ALPHA") is Alpha and reg.find("Alpha") == ("alpha", Alpha)  # one case-insensitive match
    with pytest.raises(NotFoundError, match=r"unknown gadget 'alpah'; did you mean 'alpha'\? \(available: alpha\)"):
        reg.get("alpah")
    with pytest.raises(ConfigError):  # an unknown name is a setting's error too
        reg.get("alpah")


@pytest.mark.parametrize("register, name", [
    (lambda n, o: doabench.register_tracker(n, o), "srp-max"),
    (sources.register_task_kind, "simulated"),
    (task_registry.register_prefix, "file"),
    (simulators.register_simulator, "builtin"),
])
def test_a_taken_name_is_refused_in_every_registry(register, name):
    """Task kinds, prefixes and simulators used to be overwritten silently by a second registration."""
    class Impostor(doabench.Tracker):
        pass

    with pytest.raises(ConfigError, match=f"'{name}' is (already registered|declared) by"):
        register(name, Impostor)


def test_versioned_ids_follow_gymnasiums_discipline():
    """``id`` is the latest version, ``id-vN`` exactly N; an unknown version names those that exist;
    an id that is itself registered is not read as a version; a withdrawn id raises its reason."""
    from doabench.plugins import VersionedRegistry

    reg: VersionedRegistry[tuple[str, int]] = VersionedRegistry("widget", lambda w: w[1], namespace="ns/")
    one, two, odd = ("a", 1), ("a", 2), ("a-v7", 0)
    for w in (two, one, odd):
        reg.register(w[0], w)
    assert reg.get("a") is two and reg.get("ns/a") is two and reg.get("a-v1") is one and reg.get("ns/a-v2") is two
    assert reg.get("a-v7") is odd and list(reg.versions("a")) == [1, 2] and reg.latest() == {"a": two, "a-v7": odd}
    with pytest.raises(NotFoundError, match=r"widget 'a' has no version 9 \(registered: v1, v2; `ns/a-v2` or `a`"):
        reg.get("ns/a-v9")
    with pytest.raises(NotFoundError, match=r"unknown widget 'b-v1'; did you mean 'a-v7'\? \(available: a, a-v7\)"):
        reg.get("b-v1")
    with pytest.raises(ConfigError, match="widget 'a' version 2 is already registered"):
        reg.register("a", ("a", 2, "edited"))
    reg.register("a", ("a", 2, "edited"), replace=True)
    reg.withdraw("a", "a.toml is broken")
    with pytest.raises(ConfigError, match="a.toml is broken"):
        reg.get("a-v1")
    assert reg.versions("a") == {} and reg.get("a-v7") is odd


def test_a_feature_kind_cannot_take_a_built_in_name():
    with pytest.raises(ConfigError, match="taken"):
        doabench.features.register_feature_kind(kinds.feature_kind("srp"))


def test_unknown_names_say_the_same_thing_everywhere():
    for get, name, what in ((doabench.make_tracker, "srp-mx", "tracker"),
                            (sources.task_kind, "simulatd", "task kind"),
                            (kinds.feature_kind, "spectogram", "feature kind"),
                            (simulators.get_simulator, "pyroomacoustic", "simulator")):
        with pytest.raises(NotFoundError) as caught:
            get(name)
        assert re.match(rf"unknown {what} '{name}'; did you mean '[\w-]+'.*\(available: ", str(caught.value))
    assert simulators.get_simulator("Builtin").name == "builtin"  # matched case-insensitively, as before


PLUGIN = '''
import numpy as np
import doabench
from doabench.features import FeatureKind


class Steady(doabench.Tracker):
    """Always the same direction (the plug-in's tracker, declared by entry point only)."""

    observation_spec = doabench.ObservationSpec.of(("srp_max",))

    def reset(self, array, **context):
        pass

    def step(self, observation):
        return np.array([1.0, 0.0, 0.0])


LOUDNESS = FeatureKind("loudness", lambda c: (c.array.n_mics,),
                       compute=lambda stft: stft.frames.pow(2).mean(-1).clamp_min(1e-12).log10(),
                       description="log frame power per microphone")


class LoudLinear(doabench.Tracker):
    """A learned tracker on the plug-in's loudness: one linear layer, trainable by doabench train."""

    observation_spec = doabench.ObservationSpec.of(("loudness",))

    def __init__(self, spec=None, **options):
        import torch

        super().__init__(spec, **options)
        torch.manual_seed(0)
        self.network = torch.nn.Linear(12, 3)

    def network_input(self, features):
        return features["loudness"]  # (B, T, 12)

    def save_weights(self, path, metadata):
        import json
        from safetensors.torch import save_file

        save_file(self.network.state_dict(), str(path), metadata={"doabench": json.dumps(metadata)})

    def reset(self, array, **context):
        pass

    def step(self, observation):
        return np.array([1.0, 0.0, 0.0])
'''


def _install_plugin(root) -> None:
    """A package with real installed metadata: what ``pip install`` leaves in site-packages."""
    (root / "steady_plugin").mkdir()
    (root / "steady_plugin" / "__init__.py").write_text(PLUGIN)
    (root / "broken_plugin.py").write_text("raise ImportError('needs libfoo 2.0')\n")
    info = root / "steady_plugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: steady-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(textwrap.dedent("""\
        [doabench.trackers]
        steady = steady_plugin:Steady
        broken = broken_plugin:Tracker
        srp-max = steady_plugin:Steady
        loud-linear = steady_plugin:LoudLinear

        [doabench.feature_kinds]
        loudness = steady_plugin:LOUDNESS
        """))


def _doabench(root, *argv: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": f"{root}{os.pathsep}{ROOT}", "OMP_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, "-m", "doabench", *argv], capture_output=True, text=True, env=env,
                          cwd=root, timeout=300)


@pytest.mark.slow
def test_an_installed_plug_in_is_a_peer_and_a_broken_one_is_named_in_one_line(tmp_path):
    _install_plugin(tmp_path)
    listing = _doabench(tmp_path, "list", "trackers")
    assert listing.returncode == 0, listing.stderr
    assert re.search(r"^steady\b", listing.stdout, re.M) and re.search(r"^srp-max\b", listing.stdout, re.M)
    # the broken plug-in and the one that declares a taken id are each named on one line; the rest list
    warned = [line for line in listing.stderr.splitlines() if "plug-in" in line]
    assert any("'broken'" in line and "needs libfoo 2.0" in line for line in warned), listing.stderr
    assert "Traceback" not in listing.stderr
    # asked for by name: the plug-in's tracker runs; the broken one is a one-line error, exit 2
    run = _doabench(tmp_path, "run", "--tracker", "steady", "--task", "sim-demo", "--episodes", "1", "--no-frames",
                    "--out", str(tmp_path / "results"))
    assert run.returncode == 0, run.stderr
    broken = _doabench(tmp_path, "run", "--tracker", "broken", "--task", "sim-demo", "--episodes", "1")
    assert broken.returncode == 2 and len(broken.stderr.strip().splitlines()) == 1
    assert "tracker plug-in 'broken' (broken_plugin:Tracker) failed to load: ImportError: needs libfoo 2.0" in broken.stderr
    # an id two packages declare is neither's: a one-line error naming both, never a silent winner
    srp = _doabench(tmp_path, "describe", "--tracker", "srp-max")
    assert srp.returncode == 2 and len(srp.stderr.strip().splitlines()) == 1, srp.stderr
    assert all(t in srp.stderr for t in ("'srp-max' is declared by", "doabench.trackers.srp:SrpMaxTracker",
                                         "steady_plugin:Steady")), srp.stderr
    # the installed feature kind is an observation kind like the built-ins, loaded on first use
    kind = subprocess.run(
        [sys.executable, "-c", "from doabench.features.kinds import observation_kinds, feature_kind; "
                               "print('loudness' in observation_kinds(), feature_kind('loudness').description)"],
        capture_output=True, text=True, env={**os.environ, "PYTHONPATH": f"{tmp_path}{os.pathsep}{ROOT}"}, timeout=300)
    assert kind.stdout.split() == ["True", "log", "frame", "power", "per", "microphone"], kind.stderr


@pytest.mark.slow
def test_an_installed_feature_kind_works_wherever_a_built_in_does(tmp_path):
    """The installed plug-in's kind, computed by its own compute from the shared STFT context:
    ``doabench features --kind``, ``make-dataset --features`` and ``train --dataset`` on it."""
    import h5py
    import numpy as np
    import soundfile as sf

    from doabench.corpora.fixture import write_librispeech_layout
    from doabench.framing import FrameSpec

    _install_plugin(tmp_path)
    audio = np.random.default_rng(3).normal(0, 0.1, (16000, 12)).astype(np.float32)
    sf.write(tmp_path / "rec.wav", audio, 16000, subtype="FLOAT")
    feats = _doabench(tmp_path, "features", "rec.wav", "--array", "nao", "--kind", "loudness", "--out", "loud.npy")
    assert feats.returncode == 0, feats.stderr
    spec = FrameSpec()
    frames = np.lib.stride_tricks.sliding_window_view(audio.T, spec.window, axis=1)[:, ::spec.hop]
    expected = np.log10((frames.astype(np.float64) ** 2).mean(-1)).T  # (T, 12)
    assert np.allclose(np.load(tmp_path / "loud.npy"), expected, atol=1e-4)
    assert '"description": "log frame power per microphone"' in (tmp_path / "loud.json").read_text()

    made = _doabench(tmp_path, "make-dataset", "--task", "sim-demo", "--episodes", "2", "--features",
                     "loudness,srp:4x8", "--out", "ds.h5", "--quiet")
    assert made.returncode == 0, made.stderr
    with h5py.File(tmp_path / "ds.h5") as f:
        group = f["episodes/000000"]
        loud, vad = group["features/loudness"][()], group["vad"][()]
        assert loud.shape == (len(vad), 12) and "features/srp_4x8" in group
        assert np.isfinite(loud).all() and loud[vad].min() > -12 and not loud[~vad].any()

    corpus = write_librispeech_layout(tmp_path / "LibriSpeech")
    trained = _doabench(tmp_path, "train", "--tracker", "loud-linear", "--dataset", "ds.h5", "--epochs", "1",
                        "--epoch-size", "2", "--val-trajectories", "2", "--no-compile", "--librispeech", str(corpus),
                        "--cache-root", "cache", "--out", "run", "--quiet")
    assert trained.returncode == 0, trained.stderr
    assert (tmp_path / "run" / "checkpoint.safetensors").is_file()
    assert len((tmp_path / "run" / "log.csv").read_text().strip().splitlines()) == 2  # header and epoch 1
