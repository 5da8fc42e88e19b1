"""The JSON Schema of results files (``doabench.results/2``), shipped with the package.

``results_schema()`` is the schema as a dict; ``validate_results(results)`` checks a results
dictionary (or a loaded file) against it with ``jsonschema`` (a test dependency; install it with
``pip install jsonschema`` to validate in your own code). ``results_problem(data)`` says, without
``jsonschema``, why a loaded JSON file is not a results file the leaderboards can read (the same
answer whatever is installed). ``load_results(path)`` reads a results file, or says in one line
why it cannot; every results reader goes through ``read_json(path)``, which reads only regular
files of at most :data:`MAX_JSON_BYTES` nested at most :data:`MAX_JSON_DEPTH` deep;
``read_results(path)`` is that, with a file of an older schema read through
:func:`doabench.results.upgrade.upgrade_results`.
docs/results-format.md documents the fields.
"""
from __future__ import annotations

import functools
import json
import math
import re
import stat
from importlib import resources
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from doabench.errors import InputError
from doabench.results.upgrade import upgrade_results

SCHEMA_FILE = "results-2.schema.json"
#: the sections the leaderboards read, checked by :func:`results_problem`
LEADERBOARD_SECTIONS = ("task", "tracker", "summary", "environment")
_JSON_TYPES: dict[str, tuple[type, ...]] = {"string": (str,), "integer": (int,), "number": (int, float),
                                            "boolean": (bool,), "object": (dict,), "array": (list,),
                                            "null": (type(None),)}


#: the largest JSON file read as results, in bytes: far above any run's (a grid of hundreds of
#: episodes with per-frame estimates is tens of MB)
MAX_JSON_BYTES = 1 << 30
#: the deepest nesting of arrays and objects read: a results file nests under 10 levels; deeper is
#: no results file, and parsing or walking it could exhaust Python's stack
MAX_JSON_DEPTH = 64
_STRING = re.compile(rb'"[^"\\]*(?:\\.[^"\\]*)*"')
_NOT_BRACKETS = bytes(b for b in range(256) if b not in b"[]{}")


class JsonBoundsError(InputError):
    """A file that is not parsed at all: not a regular file, larger than :data:`MAX_JSON_BYTES` or
    nested deeper than :data:`MAX_JSON_DEPTH`. ``reason`` says which, without the path."""

    def __init__(self, path: Path, reason: str) -> None:
        super().__init__(f"{path}: {reason}")
        self.reason = reason


def json_depth(text: bytes) -> int:
    """The deepest nesting of arrays and objects in JSON text (brackets inside strings skipped),
    found without parsing it."""
    brackets = _STRING.sub(b"", text).translate(None, _NOT_BRACKETS)
    if not brackets:
        return 0
    codes = np.frombuffer(brackets, dtype=np.uint8)
    return int(np.cumsum(np.where((codes == ord("[")) | (codes == ord("{")), 1, -1)).max())


def json_files(folder: Path) -> list[Path]:
    """The JSON files of a results folder, sorted by name, without doabench's own temporary files
    (their names start with a dot)."""
    return [path for path in sorted(folder.glob("*.json")) if not path.name.startswith(".")]


def read_json(path: str | Path) -> tuple[bytes, Any]:
    """``(bytes, parsed)`` of a JSON file that may come from anyone: a JsonBoundsError for one that is
    not a regular file, is larger than :data:`MAX_JSON_BYTES` or nests deeper than
    :data:`MAX_JSON_DEPTH` (checked before parsing); an InputError for text that is not JSON;
    OSError (``FileNotFoundError`` ...) as the system raises it."""
    path = Path(path)
    info = path.stat()
    if not stat.S_ISREG(info.st_mode):
        raise JsonBoundsError(path, "not a regular file")
    if info.st_size > MAX_JSON_BYTES:
        raise JsonBoundsError(path, f"{info.st_size} bytes, more than the {MAX_JSON_BYTES} a results file may have")
    with open(path, "rb") as f:
        data = f.read(MAX_JSON_BYTES + 1)
    if len(data) > MAX_JSON_BYTES:
        raise JsonBoundsError(path, f"more than the {MAX_JSON_BYTES} bytes a results file may have")
    depth = json_depth(data)
    if depth > MAX_JSON_DEPTH:
        raise JsonBoundsError(path, f"nested {depth} levels deep, more than the {MAX_JSON_DEPTH} a results file "
                                    "may have")
    try:
        return data, json.loads(data)
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as exc:
        raise InputError(f"{path} is not valid JSON ({exc})") from None


def read_results(path: str | Path) -> tuple[bytes, Any]:
    """``(bytes, parsed)`` as :func:`read_json`, a results file of an older schema read as the
    current one (:func:`doabench.results.upgrade.upgrade_results`; an UpgradeError, an InputError,
    for one whose content cannot be); other JSON as it is."""
    data, parsed = read_json(path)
    return data, upgrade_results(parsed)


@functools.lru_cache(maxsize=1)
def _schema_text() -> str:
    return resources.files("doabench.results").joinpath("schemas").joinpath(SCHEMA_FILE).read_text()


def results_schema() -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of a ``doabench.results/2`` file."""
    return json.loads(_schema_text())


def _nan_to_none(obj: Any) -> Any:
    """NaN (written as ``NaN``, e.g. an RMSAE with no non-silent frame) validates as ``null``."""
    if isinstance(obj, float) and math.isnan(obj):
        return None
    if isinstance(obj, dict):
        return {k: _nan_to_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_nan_to_none(v) for v in obj]
    return obj


def validate_results(results: Any) -> None:
    """Raise ``jsonschema.ValidationError`` if ``results`` does not follow the schema."""
    import jsonschema

    from doabench.files import to_json

    data = _nan_to_none(json.loads(to_json(results, indent=None)))  # numpy values -> JSON types, as written
    error = jsonschema.exceptions.best_match(_validator().iter_errors(data))
    if error is not None:
        raise error


@functools.lru_cache(maxsize=1)
def _validator() -> Any:
    """The schema's validator, built once: ``jsonschema.validate`` checks the schema itself against
    the draft's metaschema on every call (about a fifth of a committed file's validation time)."""
    import jsonschema

    return jsonschema.Draft202012Validator(results_schema())


def results_problem(data: Any, sections: Sequence[str] = LEADERBOARD_SECTIONS) -> str | None:
    """Why ``data`` (a loaded JSON file) is not a results file of this schema, or None: its
    ``schema`` field, then each of ``sections`` against its part of the JSON Schema, one level
    deep (the fields it requires and their JSON types). Needs no ``jsonschema``."""
    if not isinstance(data, dict):
        return "not a JSON object, so not a doabench results file"
    properties = results_schema()["properties"]
    wanted = properties["schema"]["const"]
    if "schema" not in data:
        return 'no "schema" field: not a doabench results file'
    found = data["schema"]
    if not (isinstance(found, str) and found.startswith(wanted.rsplit("/", 1)[0] + "/")):
        return f'"schema" is {json.dumps(found)}: not a doabench results file'
    if found != wanted:
        return f"results schema {found!r}; this doabench reads {wanted!r} and the schemas before it"
    for section in sections:
        problem = _section_problem(section, data.get(section), properties[section])
        if problem:
            return problem
    return None


#: how far a summary's pooled RMSAE may lie from the one its episode rows give (relative: rounding only)
SUMMARY_TOLERANCE = 1e-6
_POOLED = (("rmsae_all", "n_frames"), ("rmsae_nonsilent", "n_nonsilent"))


def summary_problem(results: Any) -> str | None:
    """Why the pooled RMSAEs of a results file's summary are not what its episode rows give, or None.
    A pooled RMS over frames is exact from the rows: ``sqrt(sum_i n_i rms_i^2 / sum_i n_i)`` over
    episodes ``i`` (``n_frames`` for ``rmsae_all``, ``n_nonsilent`` for ``rmsae_nonsilent``), so an
    edited summary (a better number than the episodes give) is found. An interval (``*_ci95``) may
    be ``null``, as a run whose episodes give none has it
    (:func:`doabench.metrics.bootstrap_ci_from_sums`); one that is given must hold its pooled value."""
    summary, rows = results.get("summary"), results.get("episodes")
    if not isinstance(summary, dict):
        return None
    for metric, count in _POOLED:
        claimed = summary.get(metric)
        if claimed is None:
            continue
        if not _is_type(claimed, "number"):
            return f"summary.{metric} is {json.dumps(claimed)}, not a number"
        if not isinstance(rows, list) or not rows:
            return f"summary.{metric} is {claimed:.4g} but the file has no episode rows it comes from"
        values, counts = [], []
        for row in rows:
            value, n = (row.get(metric), row.get(count)) if isinstance(row, dict) else (None, None)
            if not (isinstance(n, int) and _is_type(n, "integer") and n >= 0) or not (
                    value is None or _is_type(value, "number")):
                return f"episode rows hold no usable {metric} and {count} to check summary.{metric} against"
            values.append(math.nan if value is None else float(value))
            counts.append(float(n))
        rms, n = np.asarray(values), np.asarray(counts)
        total = float(n.sum())
        pooled = math.sqrt(float(np.where(n > 0, np.nan_to_num(rms) ** 2 * n, 0.0).sum()) / total) if total else math.nan
        if math.isnan(pooled) and math.isnan(claimed):
            continue
        if not abs(pooled - claimed) <= SUMMARY_TOLERANCE * max(1.0, abs(pooled)):
            return (f"summary.{metric} is {claimed:.4g} but its {len(rows)} episode rows pool to {pooled:.4g}; "
                    "the summary was not computed from them")
        ci = summary.get(f"{metric}_ci95")
        if ci is not None and not math.isnan(claimed) and not (
                isinstance(ci, list) and len(ci) == 2 and all(_is_type(v, "number") for v in ci)
                and ci[0] >= 0 and ci[0] - SUMMARY_TOLERANCE <= claimed <= ci[1] + SUMMARY_TOLERANCE):
            return (f"summary.{metric}_ci95 is {json.dumps(ci)}, which does not hold its pooled value "
                    f"{claimed:.4g}; the interval was not computed from the episodes")
    return None


def _section_problem(section: str, value: Any, schema: dict[str, Any]) -> str | None:
    """What a section lacks or holds of the wrong type, by the schema's ``required`` and ``type``."""
    if not isinstance(value, dict):
        return f"no {section!r} section (the results schema requires one)"
    for key in schema.get("required", ()):
        if key not in value:
            return f"{section}.{key} is missing (the results schema requires it)"
        types = (schema.get("properties", {}).get(key) or {}).get("type")
        names = [types] if isinstance(types, str) else list(types or ())
        if names and not any(_is_type(value[key], name) for name in names):
            return f"{section}.{key} is {json.dumps(value[key])} (the results schema wants type {' or '.join(names)})"
    return None


def _is_type(value: Any, name: str) -> bool:
    """``value`` is of the JSON type ``name`` (true and false are no numbers, NaN is a number)."""
    if isinstance(value, bool) and name in ("integer", "number"):
        return False
    return isinstance(value, _JSON_TYPES.get(name, (object,)))


def load_results(path: str | Path) -> dict[str, Any]:
    """A results JSON written by ``doabench run``, in the current schema (a file of an older one read
    through :func:`doabench.results.upgrade.upgrade_results`); a one-line InputError naming the
    reason otherwise."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path} is a folder; give results JSON files")
    try:
        _, data = read_json(path)
    except FileNotFoundError:
        raise InputError(f"results file {path} does not exist") from None
    except OSError as exc:
        raise InputError(f"results file {path} cannot be read ({exc.strerror or exc})") from None
    if not (isinstance(data, dict) and str(data.get("schema", "")).startswith("doabench.results/")):
        raise InputError(f"{path} is not a doabench results file (no doabench.results schema)")
    try:
        return upgrade_results(data)
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None

