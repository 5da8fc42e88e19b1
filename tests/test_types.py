"""doabench passes mypy (configured in pyproject.toml, [tool.mypy]): the whole package with the
default settings, the strictly typed packages with --strict's flags."""
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


# What --strict turns on, per module (warn_redundant_casts is global). pyproject.toml spells them out:
# `strict = true` in an override would apply them to every module.
STRICT_FLAGS = ("disallow_any_generics", "disallow_subclassing_any", "disallow_untyped_calls", "disallow_untyped_defs",
                "disallow_incomplete_defs", "check_untyped_defs", "disallow_untyped_decorators", "warn_unused_ignores",
                "warn_return_any", "no_implicit_reexport", "strict_equality", "extra_checks")


def mypy_config() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["mypy"]


def strict_modules() -> list[str]:
    """The modules of pyproject.toml's strict mypy override (``pkg.*`` patterns come with ``pkg``)."""
    modules: list[str] = []
    for section in mypy_config()["overrides"]:
        if section.get("disallow_untyped_defs"):
            assert all(section.get(flag) for flag in STRICT_FLAGS), section
            names = section["module"]
            modules += [names] if isinstance(names, str) else names
    return [m for m in modules if not m.endswith(".*")]


def test_strict_packages_are_listed():
    assert mypy_config().get("warn_redundant_casts")
    assert {"doabench.features", "doabench.envs", "doabench.trackers", "doabench.runner"} <= set(strict_modules())


def run_mypy(*args: str) -> subprocess.CompletedProcess:
    """``python -m mypy ARGS`` in the repository root (so with pyproject.toml's configuration)."""
    pytest.importorskip("mypy", reason="mypy is in the test extra: pip install -e '.[test]'")
    return subprocess.run([sys.executable, "-m", "mypy", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=900)


def test_mypy_strict_packages():
    done = run_mypy(*[arg for module in strict_modules() for arg in ("-p", module)])
    assert done.returncode == 0, done.stdout + done.stderr


def test_mypy_whole_package():
    """Every module, the ones outside the strict override included; the output lists the errors."""
    done = run_mypy("doabench")
    assert done.returncode == 0, done.stdout + done.stderr
