"""docs/guarantees.md lists each promise doabench makes with the test that checks it: every test
it names exists, so the page cannot promise what no test checks any more."""
from __future__ import annotations

import ast
import re

from conftest import ROOT


def test_the_guarantees_page_names_tests_that_exist():
    """Every ``tests/<file>.py::<test>`` (and ``::<test>`` of the file named before it) exists."""
    page = (ROOT / "docs" / "guarantees.md").read_text()
    missing, current = [], None
    for ref in re.findall(r"`(tests/[\w/]+\.py)?(?:::(\w+))?`", page):
        file, name = ref
        if file:
            current = ROOT / file
            if not current.is_file():
                missing.append(file)
                continue
        if name:
            defined = {n.name for n in ast.walk(ast.parse(current.read_text())) if isinstance(n, ast.FunctionDef)}
            if name not in defined:
                missing.append(f"{current.name}::{name}")
    assert not missing, f"docs/guarantees.md names tests that do not exist: {missing}"
