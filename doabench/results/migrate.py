"""Bring results files and weights files to this version's formats and names (``doabench migrate``).

A results file of an older schema is rewritten in place in the current one
(:func:`doabench.results.upgrade.upgrade_results`; :func:`plan_rewrites`, :func:`rewrite_results`),
atomically: the upgraded JSON goes to a temporary file in the same folder, is fsynced and renamed
over the old one. Its CSV of episode rows keeps its format and is left as it is. A weights file of
an older metadata format gets an upgraded copy (:func:`migrate_weights`): the same tensors, the
metadata upgraded (:func:`doabench.results.upgrade.upgrade_weights_metadata`).

A results file's name is derived from what it holds (:func:`doabench.results.writer.results_path`):
the task, the tracker, its options and the weights it ran, named by their short name when they are
shipped weights (``sim-walk__cross3d_16x32__moving-long.json``). Files written under an older
naming keep their content; :func:`plan_renames` says which ones the current naming names
otherwise, and :func:`apply_renames` renames each JSON file with its CSV sibling. Reading a file
imports nothing and runs nothing (:func:`doabench.results.schema.load_results`).
"""
from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

from doabench.errors import InputError
from doabench.files import atomic_path, write_json
from doabench.results.schema import json_files, load_results, read_json
from doabench.results.upgrade import (RESULTS_SCHEMA, WEIGHTS_FORMAT, results_version, upgrade_results,
                                      upgrade_weights_metadata)
from doabench.results.writer import results_path

#: the safetensors header key holding a weights file's metadata (JSON)
WEIGHTS_METADATA_KEY = "doabench"


@dataclass(frozen=True)
class Rewrite:
    """One results file of an older schema (``version``) and its content in the current one."""

    path: Path
    version: str
    upgraded: dict


def plan_rewrites(folder: str | Path) -> list[Rewrite]:
    """The results files of ``folder`` in an older schema, sorted by name, each with its upgraded
    content. A one-line InputError for a folder that is none, a JSON file that is no results file,
    or an older file that cannot be upgraded: nothing is rewritten then."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder} is not a folder of results files")
    rewrites = []
    for path in json_files(folder):
        try:
            _, data = read_json(path)
        except OSError as exc:
            raise InputError(f"results file {path} cannot be read ({exc.strerror or exc})") from None
        version = results_version(data)
        if version is None:
            raise InputError(f"{path} is not a doabench results file (no doabench.results schema)")
        if version != RESULTS_SCHEMA:
            try:
                rewrites.append(Rewrite(path, version, upgrade_results(data)))
            except InputError as exc:
                raise InputError(f"{path}: {exc}") from None
    return rewrites


def rewrite_results(rewrite: Rewrite) -> None:
    """Write ``rewrite.upgraded`` over its file: atomically (a temporary file in the same folder,
    fsynced, renamed over it), so the file holds the old content or the new, never a part."""
    write_json(rewrite.path, rewrite.upgraded)


def migrate_weights(path: str | Path, out: str | Path) -> tuple[str, str | None]:
    """Write ``out``: the weights file ``path`` with its metadata in the current format and its
    tensors as they are. Returns ``(format read, SHA-256 of out)``, or ``(format, None)`` for a
    file in the current format already (nothing is written); a one-line InputError for a file that
    is not a doabench weights file."""
    from safetensors import safe_open
    from safetensors.torch import save_file

    path, out = Path(path), Path(out)
    if not path.is_file():
        raise InputError(f"weights file {path} does not exist" if not path.exists() else
                         f"weights file {path} is not a regular file")
    if out.resolve() == path.resolve():
        raise InputError(f"--out {out} is the weights file itself; the migrated copy needs another name")
    try:
        with safe_open(str(path), framework="pt", device="cpu") as f:
            header = dict(f.metadata() or {})
            tensors = {k: f.get_tensor(k) for k in f.keys()}
    except Exception as exc:  # any parse failure is the user's file
        raise InputError(f"weights file {path}: not a safetensors file ({type(exc).__name__}: {exc})") from None
    try:
        meta = json.loads(header[WEIGHTS_METADATA_KEY])
    except (KeyError, json.JSONDecodeError):
        raise InputError(f"weights file {path}: no readable doabench metadata (a `doabench train` checkpoint is "
                         "exported with `doabench train --out RUN --export FILE`)") from None
    found = meta.get("format") if isinstance(meta, dict) else None
    if found == WEIGHTS_FORMAT:
        return found, None
    try:
        upgraded = upgrade_weights_metadata(meta)
    except InputError as exc:
        raise InputError(f"weights file {path}: {exc}") from None
    header = {k: v for k, v in header.items() if k != "resolution"}  # the old format's copy beside the metadata
    header[WEIGHTS_METADATA_KEY] = json.dumps(upgraded, sort_keys=True)
    with atomic_path(out, suffix=".safetensors") as tmp:
        save_file(tensors, str(tmp), metadata=header)
    return str(found), hashlib.sha256(out.read_bytes()).hexdigest()


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
    for path in json_files(folder):
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
