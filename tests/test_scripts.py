"""scripts/ holds maintainers' tools only: each script says what it is for in its first line (after a
shell script's #! line), starting with "Maintainers"; what a user needs is a doabench command."""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted(p for p in (ROOT / "scripts").iterdir() if p.suffix in (".py", ".sh"))


def purpose_line(path: Path) -> str:
    """A Python script's docstring's first line; a shell script's first comment line after #!."""
    if path.suffix == ".py":
        doc = ast.get_docstring(ast.parse(path.read_text())) or ""
        return doc.splitlines()[0] if doc else ""
    lines = path.read_text().splitlines()
    body = lines[1:] if lines and lines[0].startswith("#!") else lines
    return body[0].lstrip("# ").strip() if body and body[0].startswith("#") else ""


def test_every_script_says_what_it_is_for_in_its_first_line() -> None:
    assert SCRIPTS, "no scripts found"
    missing = [p.name for p in SCRIPTS if not purpose_line(p).startswith("Maintainers")
               or len(purpose_line(p).split()) < 6]
    assert not missing, f"first line must say, for maintainers, what the script is for: {missing}"


def test_user_analysis_lives_in_commands_not_scripts() -> None:
    """The paired comparison and the silence breakdowns are `doabench compare` options now."""
    gone = ("cross3d_targets.py", "silence_errors.py", "pause_hold_bound.py", "compare_grid_runs.py")
    assert not [name for name in gone if (ROOT / "scripts" / name).exists()]
    from doabench.cli.main import build_parser

    help_text = build_parser()._subparsers._group_actions[0].choices["compare"].format_help()
    assert "--silence" in help_text and "--hold" in help_text and "--plot" in help_text


def _ship_check():
    """scripts/ship_check_moving.py, loaded as a module."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("ship_check_moving", ROOT / "scripts" / "ship_check_moving.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_moving_talker_ship_check_fails_todays_default(tmp_path, capsys) -> None:
    """scripts/ship_check_moving.py on today's default (the committed results) as the candidate: it
    trails walking talkers by 0.8 s, so the lag checks fail; against itself the static tasks pass."""
    import shutil

    results = ROOT / "results"
    tasks = ("sim-walk", "sim-turn", "sim-grid", "sim-pauses", "sim-fan")
    if not all((results / f"{t}__cross3d_16x32__paper.json").is_file() for t in tasks):
        import pytest

        pytest.skip("the committed results are not present")
    for t in tasks:
        shutil.copy(results / f"{t}__cross3d_16x32__paper.json", tmp_path)
    module = _ship_check()
    assert module.main([str(tmp_path)]) == 1
    out = capsys.readouterr().out
    assert "FAIL  sim-walk: pooled lag 0.8 s" in out and "pass  sim-grid: 10.71 against 10.71 deg" in out
    (tmp_path / "sim-fan__cross3d_16x32__paper.json").unlink()
    assert module.main([str(tmp_path)]) == 2
    # a candidate of another resolution is compared with the paper-recipe reference, never with itself
    capsys.readouterr()
    if (results / "sim-grid__cross3d_32x64__moving.json").is_file():
        module.main([str(results), "--stem", "cross3d_32x64"])
        assert "sim-grid: 13.79 against 10.71 deg" in capsys.readouterr().out


def test_the_ship_check_says_when_its_interval_fails_a_level_candidate() -> None:
    """A static check's interval wider than the allowed loss (+0.3 deg) fails even a candidate level
    with the reference: the line says how much better one must be on those episodes."""
    module = _ship_check()
    # sim-pauses' 20 episodes: -0.53 [-2.31, +1.36] needs a candidate 1.89 - 0.3 = 1.59 deg better
    note = module.too_few_episodes(-0.53, 1.36, 20)
    assert "with 20 episodes" in note and "about 1.59 deg better" in note
    # sim-grid's 360 episodes with a level candidate, +0.03 [-0.04, +0.10]: nothing to add
    assert module.too_few_episodes(0.03, 0.10, 360) == ""
