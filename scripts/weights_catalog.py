"""Maintainers: the figures and defaults of the shipped weights' catalog (baselines/weights/catalog.json).

Names, files and training runs in the catalog are written by hand when a weights file ships. This
script fills in, from the committed results (``results/``), reading and writing the catalog and
taking each file's SHA-256 and each tracker's plain weights from :mod:`baselines.catalog`:

* each named file's ``headline``: pooled RMSAE (all frames and voice-active) and lag on every task
  with a complete run of it on the task's defaults, and where a task has no lag, why (``lag_note``);
* ``defaults``: per tracker id, the name the rule of :mod:`doabench.results.default_weights` picks
  (docs/models.md), and per tracker whose id names a map resolution (``cross3d``), the resolution of
  the rule's pick over all its resolutions.

    python scripts/weights_catalog.py            # rewrite the catalog
    python scripts/weights_catalog.py --check    # exit 1 if the catalog differs from what the results give
    python scripts/weights_catalog.py --explain  # every candidate's verdict

tests/test_weights_names.py runs the check.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from baselines import catalog as C  # noqa: E402
from doabench.geometry import resolution_text  # noqa: E402
from doabench.results.default_weights import Verdict, choose, counted_runs, headline  # noqa: E402
from doabench.results.ranking import load_runs  # noqa: E402


#: the ``lag_note`` of a task whose committed run has no lag field at all: scored before the lag was
#: measured (an older results file), which says nothing about whether the talker moves
LAG_NOT_MEASURED = "not measured: the run predates the lag measurement"


def with_lag_notes(runs: list[dict[str, Any]], tracker: str, weights_hash: str) -> dict[str, dict[str, Any]]:
    """:func:`headline`, and for each task without a lag the reason, so that ``doabench list weights``
    and ``describe`` can say why: the run's own ``lag_note`` (a still talker, estimates that do not
    follow it), or :data:`LAG_NOT_MEASURED` for a run older than the lag."""
    figures = headline(runs, tracker, weights_hash)
    counted = counted_runs(runs, tracker, weights_hash)
    for task, row in figures.items():
        if row.get("lag_s") is not None:
            continue
        summary = counted[task].get("summary") or {}
        row["lag_note"] = str(summary.get("lag_note") or "") if "lag_s" in summary else LAG_NOT_MEASURED
    return figures


def computed(results_dir: Path, data: dict[str, Any]) -> tuple[dict[str, Any], dict[str, list[Verdict]]]:
    """The catalog with ``headline`` and ``defaults`` computed from the results in ``results_dir``,
    and the verdicts behind each default."""
    runs = [r.results for r in load_runs(results_dir)]
    entries = []
    for e in data["weights"]:
        sha = C.shipped_sha256(e["file"])
        entries.append({**e, "headline": with_lag_notes(runs, e["tracker"], sha) if sha else {}})
    defaults: dict[str, str] = {}
    verdicts: dict[str, list[Verdict]] = {}
    trackers = sorted({e["tracker"] for e in entries})
    for tracker in trackers:
        mine = {e["name"]: e["headline"] for e in entries if e["tracker"] == tracker}
        chosen, verdicts[tracker] = choose(mine, C.plain_name(*C.split_tracker_id(tracker)))
        if chosen is not None:
            defaults[tracker] = chosen
    for model in sorted({t.partition(":")[0] for t in trackers if ":" in t}):
        # the bare id: the rule over every resolution's weights, named "<res>/<name>"; where none is
        # eligible, the plain weights at the resolution the catalog falls back on
        mine = {f"{e['tracker'].partition(':')[2]}/{e['name']}": e["headline"] for e in entries
                if e["tracker"].partition(":")[0] == model}
        fallback = C.plain_resolution(model)
        plain = C.plain_name(model, fallback) if fallback is not None else None
        chosen, verdicts[model] = choose(mine, f"{resolution_text(fallback)}/{plain}" if plain else None)
        if chosen is not None:
            defaults[model] = f"{model}:{chosen.partition('/')[0]}"
    return {**data, "weights": entries, "defaults": defaults}, verdicts


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", default=str(ROOT / "results"), help="results folder (default: the committed results/)")
    ap.add_argument("--check", action="store_true", help="only check; exit 1 when the catalog is out of date")
    ap.add_argument("--explain", action="store_true", help="print every candidate's verdict")
    args = ap.parse_args()
    path = C.catalog_path()
    stored = C.read_catalog()
    new, verdicts = computed(Path(args.results), stored)
    if args.explain:
        for tracker, vs in verdicts.items():
            print(f"{tracker}: default {new['defaults'].get(tracker)}")
            for v in vs:
                print(f"  {v.name}: {'eligible' if v.eligible else 'not eligible'}: {v.reason}")
    if args.check:
        if new != stored:
            print(f"{path} is out of date: run python scripts/weights_catalog.py", file=sys.stderr)
            return 1
        print(f"{path} matches the results in {args.results}")
        return 0
    if new != stored:
        print(f"wrote {C.write_catalog(new)}")
    else:
        print(f"{path} is up to date")
    return 0


if __name__ == "__main__":
    sys.exit(main())
