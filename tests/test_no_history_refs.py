"""The repository describes the software as it is: no file refers to a working session or an issue
by number ("session N", "issue N", "issue-N"). Such references date text a reader cannot place; say
what the software does, and keep the history in git."""
from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# "session" or "issue", optionally plural, then a number, also with a hyphen or "#" before it
PATTERN = re.compile(r"\b(?:session|issue)s?[ -]#?[0-9]+", re.IGNORECASE)


def _files() -> list[Path]:
    """Every text file git tracks or would track (untracked files that are not ignored too)."""
    out = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"], cwd=ROOT,
                         capture_output=True, check=True).stdout.decode()
    return [ROOT / name for name in out.split("\0") if name and (ROOT / name).is_file()]


def test_no_session_or_issue_numbers_anywhere() -> None:
    hits = []
    for path in _files():
        if path.stat().st_size > 5_000_000:
            continue
        try:
            text = path.read_text(encoding="utf-8")
        except (UnicodeDecodeError, OSError):
            continue  # binary: weights, images, audio
        for number, line in enumerate(text.splitlines(), start=1):
            if PATTERN.search(line):
                hits.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()[:120]}")
    assert not hits, "say what the software does instead of naming a session or issue:\n" + "\n".join(hits)


def test_the_long_training_tools_describe_what_they_do_not_when() -> None:
    """The scripts and pages that run a long training resumably speak of stops and deadlines (what
    they do), not of working sessions (when someone ran them)."""
    paths = [*sorted((ROOT / "scripts").glob("*.sh")), ROOT / "docs" / "training.md", ROOT / "training-runs" / "README.md"]
    hits = [f"{p.relative_to(ROOT)}:{n}" for p in paths
            for n, line in enumerate(p.read_text().splitlines(), start=1) if re.search(r"\bsessions?\b", line, re.I)]
    assert not hits, hits
    assert not (ROOT / "scripts" / "session_start.sh").exists() and (ROOT / "scripts" / "train_in_background.sh").is_file()
