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
