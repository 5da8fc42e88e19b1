"""The README's two commands leave the tracked files alone, the Makefile's torch pin is overridable,
and the Python >= 3.10 claim holds (tomli fallback for tomllib, 3.10 syntax)."""
from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from conftest import ROOT


def _recipe(target: str) -> list[str]:
    text = (ROOT / "Makefile").read_text()
    block = re.search(rf"^{re.escape(target)}:.*\n((?:\t.*\n)+)", text, re.M)
    assert block, f"no {target} target in the Makefile"
    return [line.strip() for line in block.group(1).splitlines()]


def _git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, check=True).stdout


def _demo_out() -> Path:
    (line,) = [l for l in _recipe("demo") if "doabench run" in l]
    text = (ROOT / "Makefile").read_text()
    default = re.search(r"^DEMO_OUT \?= (\S+)", text, re.M).group(1)
    out = line.split("--out", 1)[1].split()[0].replace("$(DEMO_OUT)", default)
    return Path(out)


@pytest.mark.skipif(shutil.which("git") is None or not (ROOT / ".git").exists(), reason="needs a git checkout")
def test_demo_writes_only_under_an_ignored_folder() -> None:
    import uuid

    out = _demo_out()
    assert not out.is_absolute() and out.parts[0] != "results"
    probe = out / "sim-demo__srp-max_16x32.json"
    assert _git("check-ignore", str(probe)).strip() == str(probe)  # git-ignored
    # Run the demo's own command (one episode) into a fresh sibling of its folder (same ignore
    # rule; a user's runs/demo/ is left alone) and check that no tracked file changed.
    scratch = out.parent / f".test-demo-{uuid.uuid4().hex[:8]}"
    assert _git("check-ignore", str(scratch / "x.json")).strip()
    (line,) = [l for l in _recipe("demo") if "doabench run" in l]
    argv = line.split("doabench", 1)[1].replace("$(DEMO_OUT)", str(scratch)).split() + ["--episodes", "1", "--quiet"]
    before = _git("status", "--porcelain", "--untracked-files=no")
    try:
        proc = subprocess.run([sys.executable, "-m", "doabench", *argv], cwd=ROOT, capture_output=True, text=True,
                              timeout=600)
        assert proc.returncode == 0, proc.stderr[-2000:]
        after = _git("status", "--porcelain", "--untracked-files=no")
        # Others may edit the tree concurrently: only results/ and leaderboards/ are the demo's business.
        pick = lambda text: sorted(l for l in text.splitlines() if l[3:].startswith(("results/", "leaderboards/")))  # noqa: E731
        assert pick(after) == pick(before)
        written = sorted((ROOT / scratch).glob("*"))
        assert [p.suffix for p in written] == [".csv", ".json"], written
        try:
            import jsonschema  # noqa: F401

            from doabench.results.schema import validate_results
        except ImportError:
            pass
        else:
            import json

            validate_results(json.loads(written[1].read_text()))
    finally:
        shutil.rmtree(ROOT / scratch, ignore_errors=True)


def test_committed_results_change_only_through_an_explicit_target() -> None:
    assert not any("--out results" in l for l in _recipe("demo") + _recipe("test"))
    recipe = _recipe("update-demo-results")
    assert any("--out results" in l for l in recipe) and any("doabench leaderboard" in l for l in recipe)


@pytest.mark.skipif(shutil.which("make") is None, reason="needs make")
def test_torch_pin_and_index_are_overridable() -> None:
    def dry(*overrides: str) -> str:
        return subprocess.run(["make", "-n", "-B", "setup", *overrides], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout

    default = dry()
    assert 'pip install --quiet "torch==2.13.0"' in default and "--index-url" not in default
    custom = dry("TORCH_PIN=torch==2.5.1", "TORCH_INDEX_URL=https://download.pytorch.org/whl/cpu")
    assert '"torch==2.5.1" --index-url "https://download.pytorch.org/whl/cpu"' in custom
    readme = (ROOT / "README.md").read_text()
    assert "make TORCH_INDEX_URL=https://download.pytorch.org/whl/cpu demo" in readme
    assert "TORCH_PIN=" in readme and "CUDA build" in readme


def test_python_310_claim() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["requires-python"] == ">=3.10"
    assert 'tomli>=2.0; python_version < "3.11"' in project["dependencies"]
    # Without tomllib (as on 3.10) the task specs load through tomli.
    pytest.importorskip("tomli")
    code = ("import sys; sys.modules['tomllib'] = None\n"
            "import doabench, doabench.envs.spec as s\n"
            "assert s.tomllib.__name__ == 'tomli', s.tomllib\n"
            "assert doabench.get_task_spec('sim-demo').id == 'sim-demo'\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]


def _python310() -> str | None:
    for candidate in (*map(str, Path.home().glob(".pyenv/versions/3.10*/bin/python3.10")), shutil.which("python3.10")):
        if candidate and subprocess.run([candidate, "-c", "import sys; assert sys.version_info[:2] == (3, 10)"],
                                        capture_output=True).returncode == 0:
            return candidate
    return None


@pytest.mark.skipif(_python310() is None, reason="no Python 3.10 interpreter on this machine")
def test_sources_compile_under_python_310(tmp_path: Path) -> None:
    code = ("import sys, pathlib\n"
            "bad = []\n"
            "for d in sys.argv[1:]:\n"
            "    for p in sorted(pathlib.Path(d).rglob('*.py')):\n"
            "        try: compile(p.read_text(), str(p), 'exec')\n"
            "        except SyntaxError as e: bad.append(f'{p}: {e}')\n"
            "print('\\n'.join(bad)); sys.exit(1 if bad else 0)\n")
    proc = subprocess.run([_python310(), "-c", code, "doabench", "baselines", "tasks"], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    # Standard-library names that only exist from 3.11 on.
    newer = re.compile(r"\bimport tomllib\b(?!.*\n\s*except)|datetime\.UTC\b|from datetime import UTC|\bStrEnum\b|"
                       r"typing import .*\bSelf\b|ExceptionGroup|hashlib\.file_digest|\.add_note\(")
    offenders = []
    for p in sorted([*(ROOT / "doabench").rglob("*.py"), *(ROOT / "baselines").rglob("*.py")]):
        text = p.read_text()
        for m in newer.finditer(text):
            if m.group(0).startswith("import tomllib") and "except ModuleNotFoundError" in text[m.end():m.end() + 80]:
                continue
            offenders.append(f"{p.relative_to(ROOT)}: {m.group(0)}")
    assert not offenders, offenders


def test_readme_commands_that_need_librispeech_say_so() -> None:
    import doabench

    readme = (ROOT / "README.md").read_text()
    for line in readme.splitlines():
        if line.startswith("doabench ") and "--task " in line:
            task = line.split("--task ", 1)[1].split()[0]
            speech = doabench.get_task_spec(task).params.get("speech") or {}
            if speech.get("corpus") == "librispeech":
                assert "--librispeech" in line, line


def test_readme_says_where_the_speech_and_the_weights_come_from() -> None:
    text = (ROOT / "README.md").read_text()
    for needed in ("DOABENCH_LIBRISPEECH", "doabench data download librispeech", "baselines/weights/",
                   "docs/model-cards.md"):
        assert needed in text, needed
    assert (ROOT / "docs" / "model-cards.md").is_file() and any((ROOT / "baselines" / "weights").glob("*.safetensors"))


def test_the_quick_loop_leaves_out_only_the_listed_slow_tests_and_make_test_runs_all() -> None:
    """`make test-fast` deselects the slow tests (tests/conftest.py SLOW_TESTS); `make test`, the README's
    and CI's command, selects nothing out; every listed prefix names a test file that exists."""
    from conftest import SLOW_TESTS

    makefile = (ROOT / "Makefile").read_text()
    test_rule = makefile.split("\ntest: setup\n", 1)[1].split("\n\n", 1)[0]
    fast_rule = makefile.split("\ntest-fast: setup\n", 1)[1].split("\n\n", 1)[0]
    assert "-m pytest" in test_rule and " -m " not in test_rule.replace("python -m pytest", "")
    assert '-m "not slow"' in fast_rule
    for prefix in SLOW_TESTS:
        assert (ROOT / prefix.split("::", 1)[0]).is_file(), prefix
