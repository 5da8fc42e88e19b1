"""The JSON Schema of results files (``doabench.results/1``), shipped with the package.

``results_schema()`` is the schema as a dict; ``validate_results(results)`` checks a results
dictionary (or a loaded file) against it with ``jsonschema`` (a test dependency; install it with
``pip install jsonschema`` to validate in your own code). ``results_problem(data)`` says, without
``jsonschema``, why a loaded JSON file is not a results file the leaderboards can read (the same
answer whatever is installed). ``load_results(path)`` reads a results file, or says in one line
why it cannot. docs/results-format.md documents the fields.
"""
from __future__ import annotations

import functools
import json
import math
from importlib import resources
from pathlib import Path
from typing import Any, Sequence

from doabench.errors import InputError

SCHEMA_FILE = "results-1.schema.json"
#: the sections the leaderboards read, checked by :func:`results_problem`
LEADERBOARD_SECTIONS = ("task", "tracker", "summary", "environment")
_JSON_TYPES: dict[str, tuple[type, ...]] = {"string": (str,), "integer": (int,), "number": (int, float),
                                            "boolean": (bool,), "object": (dict,), "array": (list,),
                                            "null": (type(None),)}


@functools.lru_cache(maxsize=1)
def _schema_text() -> str:
    return resources.files("doabench.results").joinpath("schemas").joinpath(SCHEMA_FILE).read_text()


def results_schema() -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of a ``doabench.results/1`` file."""
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
    jsonschema.validate(data, results_schema(), cls=jsonschema.Draft202012Validator)


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
        return f"results schema {found!r}; this doabench reads {wanted!r}"
    for section in sections:
        problem = _section_problem(section, data.get(section), properties[section])
        if problem:
            return problem
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
    """A results JSON written by ``doabench run``; a one-line InputError naming the reason otherwise."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"results file {path} does not exist") from None
    except IsADirectoryError:
        raise InputError(f"{path} is a folder; give results JSON files") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path} is not valid JSON ({exc})") from None
    if not (isinstance(data, dict) and str(data.get("schema", "")).startswith("doabench.results/")):
        raise InputError(f"{path} is not a doabench results file (no doabench.results schema)")
    return data

