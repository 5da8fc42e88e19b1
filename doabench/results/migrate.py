"""Bring a folder of results files to the names this version gives them (``doabench migrate``).

A results file's name is derived from what it holds (:func:`doabench.results.writer.results_path`):
the task, the tracker, its options and the weights it ran, named by their short name when they are
shipped weights (``sim-walk__cross3d_16x32__moving-long.json``). Files written under an older
naming keep their content; :func:`plan_renames` says which ones the current naming names
otherwise, and :func:`apply_renames` renames each JSON file with its CSV sibling. Reading a file
imports nothing and runs nothing (:func:`doabench.results.schema.load_results`).
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from doabench.errors import InputError
from doabench.results.schema import load_results
from doabench.results.writer import results_path


@dataclass(frozen=True)
class Rename:
    """One results file (``source``, a ``.json``) and the name the current naming gives it."""

    source: Path
    target: Path

    def siblings(self) -> list[tuple[Path, Path]]:
        """The JSON file and, where it exists, the CSV of the same stem, each with its new path."""
        pairs = [(self.source, self.target)]
        csv = self.source.with_suffix(".csv")
        if csv.is_file():
            pairs.append((csv, self.target.with_suffix(".csv")))
        return pairs


def plan_renames(folder: str | Path) -> list[Rename]:
    """The files of ``folder`` whose names differ from the current naming, sorted by name. A
    one-line InputError when a file is not a results file, or when two files (or a file and one
    already named so) would take the same name: nothing is renamed then."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder} is not a folder of results files")
    renames: list[Rename] = []
    names: dict[Path, Path] = {}
    for path in sorted(folder.glob("*.json")):
        target = results_path(load_results(path), folder)
        if target in names:
            raise InputError(f"{path.name} and {names[target].name} would both be named {target.name}: "
                             "they hold the same configuration; keep one")
        names[target] = path
        if target.name != path.name:
            renames.append(Rename(path, target))
    moving = {r.source for r in renames}
    for r in renames:
        for _, new in r.siblings():
            if new.exists() and new.with_suffix(".json") not in moving:
                raise InputError(f"{r.source.name} would be renamed {new.name}, which exists already")
    return renames


def apply_renames(renames: list[Rename]) -> None:
    """Rename every file of ``renames`` (JSON and CSV). The targets were checked free by
    :func:`plan_renames`; each rename is one ``os.replace``, so a file is under one name or the
    other, never lost, and a stopped migration continues when run again."""
    for r in renames:
        for old, new in r.siblings():
            os.replace(old, new)
