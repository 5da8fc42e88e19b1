"""The strictly typed packages pass mypy (configured in pyproject.toml, [tool.mypy])."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]


def strict_modules() -> list[str]:
    """The modules pyproject.toml's mypy overrides mark strict (``pkg.*`` patterns come with ``pkg``)."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    overrides = config["tool"]["mypy"]["overrides"]
    modules: list[str] = []
    for section in overrides:
        if section.get("strict"):
            names = section["module"]
            modules += [names] if isinstance(names, str) else names
    return [m for m in modules if not m.endswith(".*")]


def test_strict_packages_are_listed():
    assert "doabench.features" in strict_modules()


def test_mypy_strict_packages():
    pytest.importorskip("mypy", reason="mypy is in the test extra: pip install -e '.[test]'")
    args = [arg for module in strict_modules() for arg in ("-p", module)]
    done = subprocess.run([sys.executable, "-m", "mypy", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=900)
    assert done.returncode == 0, done.stdout + done.stderr
