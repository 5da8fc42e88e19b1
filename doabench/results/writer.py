"""Results files: one JSON per run (summary, provenance, per-episode metrics, optional frames)
and a CSV of per-episode rows, both written atomically."""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pandas as pd

from doabench.results.files import atomic_path, write_json


def results_stem(task_id: str, tracker_id: str) -> str:
    """File stem for a (task, tracker) run, safe on every filesystem: ``sim-demo__srp-max_32x64``."""
    safe = lambda s: re.sub(r"[^A-Za-z0-9.+-]+", "_", s).strip("_")  # noqa: E731
    return f"{safe(task_id)}__{safe(tracker_id)}"


def write_results(results: dict[str, Any], out_dir: str | Path) -> tuple[Path, Path]:
    """Write ``<stem>.json`` and ``<stem>.csv`` into ``out_dir``; returns both paths."""
    out_dir = Path(out_dir)
    stem = results_stem(results["task"]["id"], results["tracker"]["id"])
    json_path = write_json(out_dir / f"{stem}.json", results)
    csv_path = out_dir / f"{stem}.csv"
    with atomic_path(csv_path) as tmp:
        pd.DataFrame(results["episodes"]).to_csv(tmp, index=False, float_format="%.4f")
    return json_path, csv_path


def format_summary(results: dict[str, Any]) -> str:
    """The table ``doabench run`` prints."""
    s = results["summary"]
    lines = [
        f"task {results['task']['id']} v{results['task']['version']} | tracker {results['tracker']['id']} "
        f"| {results['task']['episodes_run']} episodes | causal: {str(results['causal']).lower()}",
        f"{'metric (pooled over frames)':<34}{'value':>10}",
        f"{'RMSAE all frames [deg]':<34}{s['rmsae_all']:>10.2f}   95% CI [{s['rmsae_all_ci95'][0]:.2f}, "
        f"{s['rmsae_all_ci95'][1]:.2f}]",
        f"{'RMSAE non-silent frames [deg]':<34}{s['rmsae_nonsilent']:>10.2f}   95% CI "
        f"[{s['rmsae_nonsilent_ci95'][0]:.2f}, {s['rmsae_nonsilent_ci95'][1]:.2f}]",
        f"{'MAE non-silent [deg]':<34}{s['pooled']['mae']:>10.2f}",
        f"{'median / p90 non-silent [deg]':<34}{s['pooled']['median']:>10.2f} / {s['pooled']['p90']:.2f}",
        f"{'within 5/10/20/30 deg [%]':<34}" + " / ".join(
            f"{100 * s['pooled'][f'within_{t}']:.0f}" for t in (5, 10, 20, 30)),
        f"{'azimuth MAE (LOCATA) [deg]':<34}{s['pooled']['azimuth_mae']:>10.2f}",
    ]
    if results.get("cells"):
        lines.append(f"{'cell':<28}{'RMSAE all':>10}{'non-silent':>12}")
        for cell, c in results["cells"].items():
            lines.append(f"{cell:<28}{c['rmsae_all']:>10.2f}{c['rmsae_nonsilent']:>12.2f}")
    rtf = results.get("real_time_factor")
    lines.append(f"wall time {results['wall_time_s']:.1f} s for {results['audio_s']:.1f} s of audio"
                 + (f" ({rtf:.1f}x real time, tracker alone {results['tracker_real_time_factor']:.0f}x)" if rtf else ""))
    return "\n".join(lines)
