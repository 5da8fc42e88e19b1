"""The test suite's own setup: the real LibriSpeech is found through ``DOABENCH_LIBRISPEECH`` as
doabench finds it, and a session ends with one line that counts the skipped tests by reason."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from conftest import ROOT, SHARED_LIBRISPEECH, librispeech_location


def test_librispeech_is_found_through_the_environment_variable_too(tmp_path: Path) -> None:
    root = tmp_path / "corpora" / "LibriSpeech"
    (root / "test-other").mkdir(parents=True)
    assert librispeech_location({"DOABENCH_LIBRISPEECH": str(root)}) == (root, "")
    found, why = librispeech_location({"DOABENCH_LIBRISPEECH": str(tmp_path / "elsewhere")})
    assert found is None and f"DOABENCH_LIBRISPEECH={tmp_path / 'elsewhere'}" in why
    found, why = librispeech_location({})  # unset: the shared copy beside the checkout
    if found is None:
        assert str(SHARED_LIBRISPEECH) in why and "DOABENCH_LIBRISPEECH" in why
    else:
        assert found == SHARED_LIBRISPEECH


def test_a_session_ends_with_one_line_of_skip_reasons(tmp_path: Path) -> None:
    (tmp_path / "test_skips.py").write_text(
        "import pytest\n"
        "def test_a(librispeech_root):\n    pass\n"
        "@pytest.mark.skip(reason='needs a GPU')\ndef test_b():\n    pass\n"
        "@pytest.mark.skip(reason='needs a GPU')\ndef test_c():\n    pass\n"
        "def test_d():\n    pass\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT / "tests"), "DOABENCH_LIBRISPEECH": str(tmp_path / "none")}
    done = subprocess.run([sys.executable, "-m", "pytest", "-p", "conftest", "-q", "-p", "no:cacheprovider",
                           "--rootdir", str(tmp_path), str(tmp_path / "test_skips.py")],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    lines = [x for x in done.stdout.splitlines() if x.startswith("skipped 3 tests: ")]
    assert lines == [f"skipped 3 tests: 2 needs a GPU; 1 real LibriSpeech test-other subset not found at "
                     f"DOABENCH_LIBRISPEECH={tmp_path / 'none'}"], done.stdout
