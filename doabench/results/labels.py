"""How a run's tracker reads in leaderboards, comparisons and figure legends: its id and, when it
had any, its options (``srp-kalman:32x64 (alpha=0.5)``), so two configurations of one tracker never
read the same. One rule for every view, so a row of a leaderboard and a line of a figure match."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Iterable, Mapping


def option_text(key: str, value: Any) -> str:
    """``key=value``; a weights file shows as its file name, not the folder it was read from."""
    if key == "weights" and isinstance(value, str) and value != "random":
        value = Path(value).name
    return f"{key}={value if isinstance(value, str) else json.dumps(value, sort_keys=True)}"


def labelled(name: str, options: Mapping[str, Any] | None, extra: Iterable[str] = ()) -> str:
    """``name`` followed by its sorted ``options`` and any ``extra`` ``key=value`` texts in brackets."""
    bits = [option_text(str(k), v) for k, v in sorted((options or {}).items())] + list(extra)
    return f"{name} ({', '.join(bits)})" if bits else name
