"""The JSON Schema of results files (``doabench.results/1``), shipped with the package.

``results_schema()`` is the schema as a dict; ``validate_results(results)`` checks a results
dictionary (or a loaded file) against it with ``jsonschema`` (a test dependency; install it with
``pip install jsonschema`` to validate in your own code). docs/results-format.md documents the fields.
"""
from __future__ import annotations

import functools
import json
import math
from importlib import resources
from typing import Any

SCHEMA_FILE = "results-1.schema.json"


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

    from doabench.results.files import to_json

    data = _nan_to_none(json.loads(to_json(results, indent=None)))  # numpy values -> JSON types, as written
    jsonschema.validate(data, results_schema(), cls=jsonschema.Draft202012Validator)
