"""The committed demo results come from a clean tree: `make update-demo-results` refuses to run
while tracked files have uncommitted changes (the results would record a commit that is not the
code that made them)."""
from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from conftest import ROOT


def _guard() -> str:
    text = (ROOT / "Makefile").read_text()
    block = re.search(r"^update-demo-results:.*\n((?:\t.*\n)+)", text, re.M).group(1)
    lines = [line.strip() for line in block.splitlines()]
    (guard,) = [line for line in lines if "git status" in line]
    assert lines.index(guard) == 0, "the clean-tree check must run before the results are written"
    return guard.lstrip("@").replace("$$", "$")  # make's escaping, as the shell sees it


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_update_demo_results_refuses_a_dirty_tree(tmp_path: Path) -> None:
    git = ["git", "-c", "user.email=t@example.org", "-c", "user.name=t"]
    subprocess.run([*git, "init", "-q", str(tmp_path)], check=True)
    (tmp_path / "code.py").write_text("x = 1\n")
    subprocess.run([*git, "-C", str(tmp_path), "add", "code.py"], check=True)
    subprocess.run([*git, "-C", str(tmp_path), "commit", "-q", "-m", "c"], check=True)
    (tmp_path / "notes.txt").write_text("untracked files do not make results dirty\n")
    clean = subprocess.run(["sh", "-c", _guard()], cwd=tmp_path, capture_output=True, text=True)
    assert clean.returncode == 0, clean.stderr
    (tmp_path / "code.py").write_text("x = 2\n")
    dirty = subprocess.run(["sh", "-c", _guard()], cwd=tmp_path, capture_output=True, text=True)
    assert dirty.returncode == 2 and "commit them first" in dirty.stderr and dirty.stderr.count("\n") == 1
