"""Documentation: the site builds in strict mode (broken links fail), generated pages are current,
and the examples the guides show are the tested files."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def _docs_gen():
    """scripts/docs_gen.py (docs-only code, outside the package), loaded as a module."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("doabench_docs_gen", ROOT / "scripts" / "docs_gen.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_mkdocs_builds_in_strict_mode(tmp_path: Path) -> None:
    pytest.importorskip("mkdocs", reason="mkdocs is in the test extra: pip install -e '.[test]'")
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (tmp_path / "site" / "tasks" / "index.html").is_file()
    assert (tmp_path / "site" / "img" / "conventions.png").is_file()


def test_generated_pages_are_current() -> None:
    """docs/tasks.md, docs/trackers.md and the example copy in adding-a-tracker.md match the registries."""
    stale = [p.name for p, text in _docs_gen().generated_pages(DOCS).items() if not p.is_file() or p.read_text() != text]
    assert not stale, f"stale generated docs {stale}: run `python scripts/docs_gen.py`"


def test_catalogues_list_registry_contents() -> None:
    tasks = (DOCS / "tasks.md").read_text()
    for task_id in _docs_gen().builtin_tasks():
        assert f"`{task_id}`" in tasks
    trackers = (DOCS / "trackers.md").read_text()
    assert "| `srp-max` | causal | srp |" in trackers and "unbounded (recursive)" in trackers


def test_adding_a_tracker_shows_the_tested_example() -> None:
    page = (DOCS / "adding-a-tracker.md").read_text()
    code = (DOCS / "examples" / "centroid_tracker.py").read_text().rstrip()
    assert f"```python\n{code}\n```" in page
    assert "--8<--" not in page  # no snippet include: plain MkDocs has no such extension


def _toml_block(page: str) -> str:
    return re.search(r"```toml\n(.*?)```", page, re.S).group(1)


def test_adding_a_task_example_is_shown_registered_and_runs(tmp_path: Path) -> None:
    example = DOCS / "examples" / "quiet-office.toml"
    assert _toml_block((DOCS / "adding-a-task.md").read_text()) == example.read_text()
    # 1. a folder on DOABENCH_TASK_PATH
    folder = tmp_path / "my-tasks"
    folder.mkdir()
    shutil.copy(example, folder)
    env = {**os.environ, "DOABENCH_TASK_PATH": str(folder)}
    proc = subprocess.run([sys.executable, "-m", "doabench.cli.main", "list", "tasks"], env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert re.search(r"^quiet-office\s+v0\s+simulated\s+2 ep", proc.stdout, re.M)
    # 2. doabench.register_task, then a real run
    import doabench

    doabench.register_task(example)
    results = doabench.run(tracker="srp-max:8x16", task="quiet-office", episodes=1, progress=False)
    assert results["task"]["id"] == "quiet-office" and results["task"]["episodes_run"] == 1
    assert 0 <= results["summary"]["rmsae_all"] < 180


def test_site_leaderboards_are_the_files_doabench_leaderboard_writes() -> None:
    """One source: every page of the site's Leaderboards section is leaderboards/<name>.md (only the
    generated-by note and the Concepts link differ), every leaderboards/*.md has a page and a nav
    entry, and the home page's headline numbers are the leaderboards' (docs_gen --check covers the
    page texts; this names the drift)."""
    site = _docs_gen()._site()
    stale = site.stale_leaderboard_copies(DOCS)
    assert not stale, f"docs/leaderboards differs from leaderboards/ for {stale}: run `python scripts/docs_gen.py`"
    nav = (ROOT / "mkdocs.yml").read_text()
    for path in (ROOT / "leaderboards").glob("*.md"):
        page = "index.md" if path.name == "summary.md" else path.name
        assert f"leaderboards/{page}" in nav, f"{page} is not in mkdocs.yml's nav"
        copy = (DOCS / "leaderboards" / page).read_text()
        assert copy == site.leaderboard_page(path.read_text(), f"leaderboards/{path.name}")
    home = (DOCS / "index.md").read_text()
    for row in site.task_rows("sim-grid")[:3]:
        assert f"`{row['tracker']}`" in home and site._with_ci(row, "rmsae_all") in home


def test_model_cards_cover_every_shipped_weights_file() -> None:
    cards = (DOCS / "model-cards.md").read_text()
    for name, sha in _docs_gen()._site().shipped_weights():
        assert sha[:16] in cards, f"no model card for baselines/weights/{name}"
    for heading in ("**Benchmark scores**", "**Reproduce**", "| training distribution |", "| validation |",
                    "**Known limits.**"):
        assert heading in cards


def test_the_engines_block_ranks_and_pairs_renderings_of_the_same_scenes(tmp_path: Path) -> None:
    """Two trackers on the same scenes rendered by two engines: each engine's pooled RMSAE on the
    shared scenes, the trackers' rank under it, the by-seed paired difference from the reference
    engine, and whether the order held, all computed from the results files."""
    import json

    site = _docs_gen()._site()

    def results(tracker: str, task: str, simulator: str, errors: list[float], seeds: list[int]) -> str:
        rows = [{"episode": i, "task": task, "seed": s, "t60": 0.3, "snr": 5.0, "recording": None, "rmsae_all": e,
                 "rmsae_nonsilent": e, "mae": e, "within_10": 1.0, "azimuth_mae": e, "n_frames": 10,
                 "n_nonsilent": 8} for i, (e, s) in enumerate(zip(errors, seeds))]
        name = f"{task}__{tracker}.json"
        (tmp_path / name).write_text(json.dumps({
            "schema": "doabench.results/1", "summary": {}, "environment": {}, "scoring": {}, "episodes": rows,
            "task": {"id": task, "version": 1, "episodes_run": len(rows), "source": {"simulator": simulator}},
            "tracker": {"id": tracker, "name": tracker}}))
        return name

    base = [4.0, 6.0, 5.0, 7.0, 6.0, 8.0, 5.0, 9.0, 6.0, 7.0]
    seeds = list(range(100, 110))
    files = [results("near", "walk", "builtin", base + [50.0, 50.0], seeds + [998, 999]),  # two scenes not shared
             results("far", "walk", "builtin", [e + 3 for e in base], seeds),
             results("near", "walk-other", "other", [e + 5 for e in base], seeds),
             results("far", "walk-other", "other", [e + 3 for e in base], seeds)]
    text = site.engines_block(files, tmp_path)
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    assert "| tracker | `walk` (builtin) | `walk-other` (other) |" in text and "pooled over the 10 scenes" in text
    assert f"| `near` | {rms(base):.2f} (#1) | {rms(np.add(base, 5)):.2f} (#2), +" in text
    assert f"| `far` | {rms(np.add(base, 3)):.2f} (#2) | {rms(np.add(base, 3)):.2f} (#1), +0.00 [+0.00, +0.00] |" in text
    assert "Order kept (all frames): none." in text
    assert re.search(r"Swapped under `walk-other`: `near` − `far` is -\S+ \[-\S+, -\S+\] \(better\) under `walk` "
                     r"and \+\S+ \[\+\S+, \+\S+\] \(worse\) under `walk-other`\.", text), text
    with pytest.raises(ValueError, match="no results for far on walk-other"):
        site.engines_block(files[:3], tmp_path)
