"""Errors a new user meets: plugin import errors name the module or class, Python
callers are told the keyword argument, `python -m doabench` works."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

import doabench
from doabench.cli.main import main
from doabench.errors import NotFoundError

from conftest import ROOT


def _err(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err, err
    return err


def test_plugin_module_not_on_the_path(capsys) -> None:
    assert main(["describe", "--tracker", "mymod_not_here:MyTracker"]) == 2
    err = _err(capsys)
    assert "cannot import module mymod_not_here" in err and "PYTHONPATH" in err and "unknown tracker" not in err


def test_misspelt_plugin_class(tmp_path: Path, monkeypatch, capsys) -> None:
    (tmp_path / "mymod_plugin.py").write_text(
        "import numpy as np, doabench\n"
        "class MyTracker(doabench.Tracker):\n"
        "    observation_spec = doabench.ObservationSpec.of(('srp_max',))\n"
        "    def step(self, observation):\n"
        "        return np.array([1.0, 0.0, 0.0])\n"
        "NOT_A_TRACKER = 3\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert main(["describe", "--tracker", "mymod_plugin:MyTrackr"]) == 2
    err = _err(capsys)
    assert "module mymod_plugin has no class 'MyTrackr'; did you mean MyTracker?" in err
    assert main(["describe", "--tracker", "mymod_plugin:NOT_A_TRACKER"]) == 2
    assert "is not a doabench.Tracker subclass (it is int" in _err(capsys)
    assert main(["describe", "--tracker", "mymod_plugin:MyTracker"]) == 0


def test_a_misspelt_registered_id_still_suggests(capsys) -> None:
    assert main(["describe", "--tracker", "srp-mx:16x32"]) == 2
    assert "unknown tracker 'srp-mx'" in _err(capsys)


def test_python_callers_are_told_the_keyword(monkeypatch) -> None:
    monkeypatch.delenv("DOABENCH_LIBRISPEECH", raising=False)
    monkeypatch.delenv("DOABENCH_LOCATA", raising=False)
    with pytest.raises(NotFoundError, match=r"librispeech=PATH"):
        doabench.run(tracker="srp-max:4x8", task="sim-grid", episodes=1, progress=False)
    with pytest.raises(NotFoundError, match=r"locata_root=PATH"):
        doabench.run(tracker="srp-max:4x8", task="locata-1", progress=False)


def test_python_dash_m_doabench() -> None:
    proc = subprocess.run([sys.executable, "-m", "doabench", "list", "tasks"], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0 and "sim-demo" in proc.stdout, proc.stderr[-2000:]
    proc = subprocess.run([sys.executable, "-m", "doabench", "--version"], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0 and proc.stdout.startswith("doabench ")


def test_one_call_srp_api_takes_one_or_many_recordings() -> None:
    import numpy as np

    from doabench.features.functional import plane_wave_delays

    nao = doabench.get_array("nao")
    rng = np.random.default_rng(0)
    s = rng.standard_normal(16000 + 200)
    truth = np.array([0.0, 1.0, 1.0]) / np.sqrt(2.0)
    tau = plane_wave_delays(nao.positions, truth, 16000)  # (mics,) delays in samples
    audio = np.stack([np.roll(s, int(round(t)))[100:16100] for t in tau])
    one = doabench.srp_maps(audio, "nao", resolution=(16, 32))
    assert one.maps.shape == (one.times.shape[0], 16, 32) and one.maps.max() <= 1.0 + 1e-6
    assert one.colatitudes.shape == (16,) and one.azimuths.shape == (32,)
    assert one.colatitudes[0] == 0 and np.isclose(one.colatitudes[-1], np.pi) and one.azimuths[0] == -np.pi
    err = np.degrees(np.arccos(np.clip(one.directions @ truth, -1, 1)))
    assert np.median(err) < 15, err
    many = doabench.srp_maps(np.stack([audio, audio]), "nao", resolution=(16, 32))
    assert many.maps.shape == (2, *one.maps.shape) and np.allclose(many.maps[1], one.maps, atol=1e-5)
    with pytest.raises(doabench.DoabenchError, match="channels"):
        doabench.srp_maps(audio[:5], "nao")


def test_the_array_file_page_example_loads(tmp_path: Path) -> None:
    import re

    page = (ROOT / "docs" / "arrays.md").read_text()
    yaml_text = re.search(r"```yaml\n(.*?)```", page, re.S).group(1)
    json_text = re.search(r"```json\n(.*?)```", page, re.S).group(1)
    (tmp_path / "ring.yaml").write_text(yaml_text)
    (tmp_path / "a.json").write_text(json_text)
    ring = doabench.load_array_file(tmp_path / "ring.yaml")
    assert ring.name == "ring-6" and ring.n_mics == 6 and ring.planar
    a = doabench.load_array_file(tmp_path / "a.json")
    assert a.name == "my-array" and not a.planar


def test_simulate_on_the_official_root_picks_a_test_subset(librispeech_root, tmp_path: Path, capsys) -> None:
    """The root holds several subsets (here test-other and train-clean-100): no --subset needed."""
    assert main(["simulate", "--librispeech", str(librispeech_root), "--duration", "2", "--seed", "1",
                 "--out", str(tmp_path / "scene")]) == 0
    out = capsys.readouterr().out
    assert "librispeech speech (subset test-other)" in out, out
