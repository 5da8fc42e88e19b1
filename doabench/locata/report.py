"""What ``doabench locata-eval`` writes: the results JSON, the per-task table, the truth files.

* JSON (``SCHEMA``): ``measures``, ``recordings`` (one object per task, recording and array with
  ``sources`` by name, ``far``, ``far_vap``, ``mota``, ``ospa_deg``) and ``tasks`` (the task
  averages by task number and array); angles in degrees, rates per second; NaN is ``null``.
* Markdown: one row per task and array, the challenge's table columns.
* Truth: per recording ``task<N>/recording<R>/<array>/truth_<source>.csv`` with the header
  :data:`TRUTH_HEADER`: seconds since the first array-audio time stamp, LOCATA's azimuth and
  inclination in radians and the VAD (0/1), on exactly the scored stamps.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from doabench._version import __version__
from doabench.locata.evaluate import Evaluation
from doabench.locata.measures import GATE_DEG, OSPA_CUTOFF_DEG, OSPA_ORDERS, ospa_key

SCHEMA = "doabench.locata-eval/1"
MARKDOWN_MARK = "<!-- written by doabench locata-eval -->"
TRUTH_HEADER = "time_s,azimuth,inclination,vad"


def finite_or_null(obj: Any) -> Any:
    """``obj`` with every non-finite float replaced by None (JSON ``null``)."""
    if isinstance(obj, dict):
        return {k: finite_or_null(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_null(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def results(evaluation: Evaluation) -> dict[str, Any]:
    """The ``--out`` JSON object (module docstring)."""
    recordings = []
    for r in evaluation.recordings:
        recordings.append({"task": r.task, "recording": r.recording, "array": r.array,
                           "tracks": int(r.tracks.azimuth.shape[0]), **r.measures.to_json()})
    return finite_or_null({
        "schema": SCHEMA,
        "doabench_version": __version__,
        "measures": evaluation.mode,
        "split": evaluation.split,
        "submission": str(evaluation.submission),
        "locata_root": str(evaluation.root),
        "gate_deg": GATE_DEG,
        "ospa_cutoff_deg": OSPA_CUTOFF_DEG,
        "ospa_orders": list(OSPA_ORDERS),
        "recordings": recordings,
        "tasks": {str(task): arrays for task, arrays in sorted(evaluation.tasks.items())},
        "warnings": list(evaluation.warnings),
    })


def written_by_locata_eval(path: Path) -> bool:
    """True when ``path`` is a JSON file that ``locata-eval`` wrote (its ``schema``)."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        return False
    return isinstance(data, dict) and data.get("schema") == SCHEMA


def markdown_written_by_locata_eval(path: Path) -> bool:
    """True when ``path`` is a Markdown table that ``locata-eval`` wrote (its first line)."""
    try:
        with open(path, encoding="utf-8") as f:
            return f.readline().rstrip("\n") == MARKDOWN_MARK
    except (OSError, UnicodeDecodeError):
        return False


def _cell(x: Any, digits: int = 2) -> str:
    return "–" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{digits}f}"


COLUMNS = (("az_error_ungated_deg", "azimuth error [°]", 2), ("az_error_deg", "gated [°]", 2),
           ("inc_error_deg", "inclination [°]", 2), ("pd", "Pd", 3), ("latency_s", "latency [s]", 2),
           ("swap_rate", "swap rate [1/s]", 3), ("frag_rate", "frag. rate [1/s]", 3), ("far", "FAR [1/s]", 2),
           ("far_vap", "FAR VAP [1/s]", 2))


def markdown(evaluation: Evaluation) -> str:
    """The per-task table (first line :data:`MARKDOWN_MARK`)."""
    head = ["task", "array", "recordings", *(title for _, title, _ in COLUMNS),
            *(f"OSPA p={ospa_key(p)} [°]" for p in OSPA_ORDERS)]
    lines = [MARKDOWN_MARK, "",
             f"LOCATA measures ({evaluation.mode}), {evaluation.split} split, submission `{evaluation.submission}`; "
             f"azimuth error ungated (the challenge's headline) and gated at {GATE_DEG:g}°, OSPA cut-off "
             f"{OSPA_CUTOFF_DEG:g}°; means over recordings as in the challenge's tables.", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for task, arrays in sorted(evaluation.tasks.items()):
        for array, avg in sorted(arrays.items()):
            cells = [str(task), array, ",".join(map(str, avg["recordings"]))]
            cells += [_cell(avg[key], digits) for key, _, digits in COLUMNS]
            cells += [_cell(avg["ospa_deg"][ospa_key(p)]) for p in OSPA_ORDERS]
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def truth_files(evaluation: Evaluation) -> dict[Path, str]:
    """Relative path -> CSV text of every scored recording's truth (module docstring)."""
    out = {}
    for r in evaluation.recordings:
        t = r.truth
        folder = Path(f"task{r.task}") / f"recording{r.recording}" / r.array
        for s, name in enumerate(t.sources):
            rows = [TRUTH_HEADER] + [f"{time:.6f},{az:.9f},{inc:.9f},{int(v)}" for time, az, inc, v in
                                     zip(t.times.tolist(), t.azimuth[s].tolist(), t.inclination[s].tolist(),
                                         t.vad[s].tolist())]
            out[folder / f"truth_{name}.csv"] = "\n".join(rows) + "\n"
    return out


def truth_file_ours(path: Path) -> bool:
    """True when ``path`` does not exist or is a truth file ``locata-eval`` wrote (its header)."""
    if not path.exists() and not path.is_symlink():
        return True
    try:
        with open(path, encoding="utf-8") as f:
            return f.readline().rstrip("\n") == TRUTH_HEADER
    except (OSError, UnicodeDecodeError):
        return False


def run_lines(block: dict[str, Any]) -> str:
    """What ``doabench run`` prints of a LOCATA run's ``locata`` results block: the challenge's
    headline measures per mode and SRP-DNN's protocol."""
    lines = []
    for mode in ("official", "corrected"):
        avg = block[mode]
        lines.append(f"LOCATA measures ({mode}): azimuth error {_cell(avg['az_error_ungated_deg'])} deg, "
                     f"Pd {_cell(avg['pd'], 3)}, latency {_cell(avg['latency_s'])} s, FAR {_cell(avg['far'])} /s, "
                     f"OSPA(p=1) {_cell(avg['ospa_deg']['1'])} deg")
    srp = block["srp_dnn"]
    lines.append(f"SRP-DNN protocol: accuracy {_cell(None if srp['accuracy'] is None else 100 * srp['accuracy'], 1)} %, "
                 f"azimuth MAE {_cell(srp['az_mae_deg'])} deg, RMSE {_cell(srp['az_rmse_deg'])} deg")
    return "\n".join(lines)
