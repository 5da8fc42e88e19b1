"""Errors a new user meets (issue 15): plugin import errors name the module or class, Python
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
        "    features = ('srp_max',)\n"
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
