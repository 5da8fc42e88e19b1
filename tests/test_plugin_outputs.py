"""A plug-in's output is checked against what it declares, as a user meets it: an installed package
(its ``.dist-info`` in a temporary folder) brings feature kinds and trackers that misbehave, and
``doabench features``, ``make-dataset``, ``run`` and ``describe`` stop with one line naming the
kind or tracker, exit status 2, and write nothing. A kind's frames are real, finite float32 of the
shape it declares; a tracker's grid is bounded before anything of its size is allocated."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from conftest import ROOT, tiny_task_toml

PLUGIN = '''
import numpy as np
import torch

import doabench
from doabench.features import FeatureKind


def power(stft):
    """(batch, frames, mics): the mean power of each frame and microphone."""
    return stft.frames.pow(2).mean(-1)


def per_mic(c):
    return (c.array.n_mics,)


DOUBLED = FeatureKind("doubled", per_mic, compute=lambda s: torch.cat([power(s), power(s)], -1))
NANNY = FeatureKind("nanny", per_mic, compute=lambda s: power(s) * float("nan"))
CPLX = FeatureKind("cplx", per_mic, compute=lambda s: s.spectra[..., 1])
BOOM = FeatureKind("boom", per_mic, compute=lambda s: {}["no such stage"])
NUMPYISH = FeatureKind("numpyish", per_mic, compute=lambda s: power(s).numpy())
SHAPELESS = FeatureKind("shapeless", lambda c: c.no_such_field, compute=power)
NEGATIVE = FeatureKind("negative", lambda c: (-3,), compute=power)
HUGE = FeatureKind("huge", lambda c: (100000, 100000), compute=power)
BADAXES = FeatureKind("badaxes", per_mic, compute=power, axes=lambda c: 1 / 0)
GOOD = FeatureKind("good", per_mic, compute=power)


class Reads(doabench.Tracker):
    def reset(self, array, **context):
        pass

    def step(self, observation):
        return np.array([1.0, 0.0, 0.0])


class ReadsDoubled(Reads):
    observation_spec = doabench.ObservationSpec.of(("doubled",))


class ReadsNanny(Reads):
    observation_spec = doabench.ObservationSpec.of(("nanny",))


class FineGrid(Reads):
    @property
    def observation_spec(self):  # built when asked: the grid is out of bounds
        return doabench.ObservationSpec.of(("srp",), (100000, 100000))


class NegativeGrid(Reads):
    @property
    def observation_spec(self):
        return doabench.ObservationSpec.of(("srp",), (-4, 8))
'''

KINDS = ("doubled", "nanny", "cplx", "boom", "numpyish", "shapeless", "negative", "huge", "badaxes", "good")
TRACKERS = {"reads-doubled": "ReadsDoubled", "reads-nanny": "ReadsNanny", "fine-grid": "FineGrid",
            "negative-grid": "NegativeGrid"}
TASK = "plugin-outputs-tiny"

# One process runs several commands through the CLI's own entry point (doabench.cli.main.main),
# each with its standard error captured: the installed package is found as a user's is, and the
# imports are paid once.
DRIVER = '''
import contextlib, io, json, sys
from doabench.cli.main import main

results = []
for argv in json.loads(sys.argv[1]):
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = main(argv)
    results.append({"code": code, "err": err.getvalue()})
print(json.dumps(results))
'''


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """A folder holding the plug-in package with real installed metadata, a tiny task and a WAV."""
    import soundfile as sf

    root = tmp_path_factory.mktemp("plugin")
    (root / "unruly_plugin").mkdir()
    (root / "unruly_plugin" / "__init__.py").write_text(PLUGIN)
    info = root / "unruly_plugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: unruly-plugin\nVersion: 0.1\n")
    kinds = "\n".join(f"{k} = unruly_plugin:{k.upper()}" for k in KINDS)
    trackers = "\n".join(f"{t} = unruly_plugin:{c}" for t, c in TRACKERS.items())
    (info / "entry_points.txt").write_text(f"[doabench.feature_kinds]\n{kinds}\n\n[doabench.trackers]\n{trackers}\n")
    (root / "tasks").mkdir()
    (root / "tasks" / f"{TASK}.toml").write_text(tiny_task_toml(TASK, episodes=2, base_seed=5))
    audio = np.random.default_rng(1).normal(0, 0.1, (16000, 12)).astype(np.float32)
    sf.write(root / "rec.wav", audio, 16000, subtype="FLOAT")
    return root


def _cli(root, *commands: list[str]) -> list[dict]:
    env = {**os.environ, "PYTHONPATH": f"{root}{os.pathsep}{ROOT}", "OMP_NUM_THREADS": "1",
           "DOABENCH_TASK_PATH": str(root / "tasks")}
    done = subprocess.run([sys.executable, "-c", DRIVER, json.dumps(list(commands))], capture_output=True,
                          text=True, env=env, cwd=root, timeout=600)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def _one_line(result: dict) -> str:
    err = result["err"].strip()
    assert result["code"] == 2, result
    assert "\n" not in err and "Traceback" not in err, err
    return err


def _nothing_written(root, *names: str) -> None:
    left = [p.name for p in root.iterdir() if p.name.startswith(names) or p.name.startswith(".")]
    assert not left, left


BAD_KINDS = {
    "doubled": "feature kind 'doubled' returned shape (1, 4, 24); it declares (12,) a frame, so (1, 4, 12) was expected",
    "nanny": "feature kind 'nanny' returned NaN or infinite values",
    "cplx": "feature kind 'cplx' returned complex64 values; a kind's frames are real float32",
    "boom": "feature kind 'boom' raised in compute(): KeyError: 'no such stage'",
    "numpyish": "feature kind 'numpyish' returned ndarray; expected a float32 torch tensor",
    "shapeless": "feature kind 'shapeless' raised in frame_shape(): AttributeError:",
    "negative": "feature kind 'negative' declares the frame shape (-3,); expected a tuple of whole sizes",
    "huge": "feature kind 'huge': one frame of shape (100000, 100000) holds 10000000000 values, more than the "
            "limit of 67108864",
    "badaxes": "feature kind 'badaxes' raised in axes(): ZeroDivisionError: division by zero",
}


@pytest.mark.slow
def test_a_plug_in_kind_that_breaks_its_declaration_is_one_line_and_writes_nothing(installed):
    """``doabench features``: every way a kind can break its declaration is one line naming the kind,
    and no .npy (whose header would disagree with its data) or sidecar is left."""
    commands = [["features", "rec.wav", "--kind", kind, "--out", f"out_{kind}.npy"] for kind in BAD_KINDS]
    commands.append(["features", "rec.wav", "--kind", "good", "--out", "out_good.npy"])
    *bad, good = _cli(installed, *commands)
    for kind, result in zip(BAD_KINDS, bad):
        assert BAD_KINDS[kind] in _one_line(result), (kind, result)
    _nothing_written(installed, *(f"out_{kind}" for kind in BAD_KINDS))
    # a kind that keeps its declaration still works, and its file's header and data agree
    assert good["code"] == 0, good
    data = np.load(installed / "out_good.npy")
    assert data.shape == (4, 12) and data.dtype == np.float32 and np.isfinite(data).all()
    assert (installed / "out_good.npy").stat().st_size == 128 + data.nbytes  # nothing beyond the header's shape


@pytest.mark.slow
def test_make_dataset_and_run_check_a_plug_in_kind_the_same_way(installed):
    """``make-dataset --features`` and ``run`` with a tracker that reads the kind: one line naming the
    kind, no dataset file, no results file."""
    made = _cli(installed,
                ["make-dataset", "--task", TASK, "--episodes", "1", "--features", "doubled", "--out", "ds_d.h5",
                 "--quiet"],
                ["make-dataset", "--task", TASK, "--episodes", "1", "--features", "cplx", "--out", "ds_c.h5",
                 "--quiet"],
                ["run", "--tracker", "reads-doubled", "--task", TASK, "--episodes", "1", "--out", "res_d",
                 "--quiet"],
                ["run", "--tracker", "reads-nanny", "--task", TASK, "--episodes", "1", "--out", "res_n",
                 "--quiet"])
    assert "feature kind 'doubled' returned shape (1, " in _one_line(made[0])
    assert "feature kind 'cplx' returned complex64 values" in _one_line(made[1])
    assert "feature kind 'doubled' returned shape (1, " in _one_line(made[2])
    assert "feature kind 'nanny' returned NaN or infinite values" in _one_line(made[3])
    # no dataset and no episode part: the journal folder keeps its configuration only, as after any
    # failed run (the same command resumes)
    assert not list(installed.glob("ds_*.h5")) and not list(installed.glob("ds_*.h5.partial"))
    for parts in installed.glob("ds_*.h5.parts"):
        assert [p.name for p in parts.iterdir()] == ["config.json"], list(parts.iterdir())
    _nothing_written(installed, "res_")


@pytest.mark.slow
def test_a_plug_in_trackers_grid_is_bounded_before_it_is_allocated(installed):
    """A tracker declaring a 100000 x 100000 grid (40 GB a map) or a negative one: one line saying
    the size and the limit, from ``track`` and ``run``, before any observation space is built."""
    results = _cli(installed,
                   ["track", "rec.wav", "--tracker", "fine-grid", "--out", "res_t.csv"],
                   ["run", "--tracker", "fine-grid", "--task", TASK, "--episodes", "1", "--out", "res_f", "--quiet"],
                   ["run", "--tracker", "negative-grid", "--task", TASK, "--episodes", "1", "--out", "res_g",
                    "--quiet"])
    for result in results[:2]:
        err = _one_line(result)
        assert "tracker 'fine-grid': resolution 100000x100000 is too fine: at most 1024 per side and 131072 grid " \
               "points" in err, err
    assert "tracker 'negative-grid': resolution -4x8: both N_theta and N_phi must be at least 2" in \
        _one_line(results[2])
    _nothing_written(installed, "res_")


def test_checked_output_refuses_what_a_kind_does_not_declare():
    """The check itself, on tensors: the declared shape, real values, finite, returned as float32."""
    import torch

    from doabench.errors import FeatureKindError
    from doabench.features import FeatureKind
    from doabench.features.transforms import checked_output

    kind = FeatureKind("probe", lambda c: (3,), compute=lambda s: None)
    assert checked_output(kind, torch.ones(1, 2, 3, dtype=torch.float64), (1, 2, 3)).dtype == torch.float32
    for value, message in ((torch.ones(1, 2, 6), r"shape \(1, 2, 6\)"),
                           (torch.ones(1, 2, 3, dtype=torch.complex64), "complex64"),
                           (torch.ones(1, 2, 3, dtype=torch.bool), "bool"),
                           (torch.full((1, 2, 3), float("inf")), "NaN or infinite"),
                           (torch.tensor([[[0.0, 0, 0], [0, 1e39, 0]]], dtype=torch.float64), "the first in frame 1"),
                           ([1, 2, 3], "returned list")):
        with pytest.raises(FeatureKindError, match=message):
            checked_output(kind, value, (1, 2, 3))

