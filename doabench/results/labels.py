"""How a run's tracker reads in leaderboards, comparisons and figure legends: its id and, when it
had any, its options (``srp-kalman:32x64 (alpha=0.5)``; shipped weights by their short name,
``cross3d:16x32 (weights=moving)``, whether or not the run named them), and the task options the run used where
they differ from the task's (``srp-max:16x32 [backend=pyroomacoustics]``), so two configurations
never read the same. One rule for every view, so a row of a leaderboard and a line of a figure match.

A results file may come from anyone, and its texts end up in Markdown that a site renders and in
CSV that spreadsheets open. The views read it through :func:`inert_texts`, which escapes in every
text what would open an HTML tag, close a code span, break a line or make a Markdown link, and
write CSV cells through :func:`csv_cell`, which keeps a text from being read as a formula."""
from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any, Iterable, Mapping

from doabench.results.identity import canonical_id, results_task_options, results_weights_name


#: a backtick (it would close a code span) as an HTML entity; line breaks as spaces
_INERT = str.maketrans({"`": "&#96;", "\n": " ", "\r": " "})
#: a ``<`` that opens an HTML tag, comment or Markdown autolink (before a letter, ``/``, ``!`` or ``?``)
_TAG_OPEN = re.compile(r"<(?=[A-Za-z/!?])")
_NUMBER_TYPES = (int, float, bool, type(None))
#: what starts a spreadsheet formula (OWASP's list for CSV injection)
FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")


def inert_text(text: str) -> str:
    """``text`` as a view shows it: a ``<`` that would open a tag and a backtick as HTML entities (no
    HTML element, no code span closed early), line breaks as spaces, and ``](`` with its
    parenthesis escaped (no Markdown link). Texts doabench writes hold none of them (``<5``, a
    speed band, opens no tag), so they read as before."""
    return _TAG_OPEN.sub("&lt;", text.translate(_INERT)).replace("](", "]&#40;")


def inert_texts(data: Any) -> Any:
    """``data`` (a loaded results file) with every text, keys included, made :func:`inert_text`."""
    if isinstance(data, str):
        return inert_text(data)
    if isinstance(data, dict):
        return {inert_text(k) if isinstance(k, str) else k: inert_texts(v) for k, v in data.items()}
    if isinstance(data, list):
        if all(isinstance(v, _NUMBER_TYPES) for v in data):  # the long lists: numbers only
            return data
        return [inert_texts(v) for v in data]
    return data


def csv_cell(value: Any) -> Any:
    """A CSV cell no spreadsheet reads as a formula: a text starting with one of
    :data:`FORMULA_STARTS` that is not a number gets a leading ``'``; anything else is kept."""
    if isinstance(value, str) and value.startswith(FORMULA_STARTS):
        try:
            float(value)
        except ValueError:
            return "'" + value
    return value


def option_text(key: str, value: Any) -> str:
    """``key=value``; a weights file shows as its file name, not the folder it was read from."""
    if key == "weights" and isinstance(value, str) and value != "random":
        value = Path(value).name
    return f"{key}={value if isinstance(value, str) else json.dumps(value, sort_keys=True)}"


def labelled(name: str, options: Mapping[str, Any] | None, extra: Iterable[str] = ()) -> str:
    """``name`` followed by its sorted ``options`` and any ``extra`` ``key=value`` texts in brackets."""
    bits = [option_text(str(k), v) for k, v in sorted((options or {}).items())] + list(extra)
    return f"{name} ({', '.join(bits)})" if bits else name


def configuration_label(name: str, options: Mapping[str, Any] | None, task_options: Mapping[str, Any] | None = None,
                        extra: Iterable[str] = ()) -> str:
    """:func:`labelled`, then the run's task options in square brackets when it had any."""
    text = labelled(name, options, extra)
    if task_options:
        text += " [" + ", ".join(option_text(str(k), v) for k, v in sorted(task_options.items())) + "]"
    return text


def run_label(results: Mapping[str, Any], extra: Iterable[str] = ()) -> str:
    """The label of a results file's configuration: canonical id, options with the shipped
    weights' name (``cross3d:16x32 (weights=paper)`` for a run of the plain weights too), then
    ``extra`` and its task options."""
    tracker = results.get("tracker") or {}
    options = dict(tracker.get("options") or {})
    name = results_weights_name(results)
    if name is not None:
        options["weights"] = name
    return configuration_label(canonical_id(dict(results)), options, results_task_options(results), extra)
