"""Check the Cross3D targets of the paper-scale training issue from results files; print Markdown.

Targets (issue 12, sections 4 and 5):

* sim-grid: ``cross3d:16x32`` pooled all-frames RMSAE <= 10 deg; over all frames it beats
  ``srp-max:16x32`` in every cell with T60 >= 0.3 s and ``srp-kalman:32x64`` in every cell with
  T60 >= 0.6 s; ``cross3d:4x8`` beats ``max-cnn1d:64x128`` (pooled, the paper's Fig. 8 claim).
* sim-pauses and sim-fan: ``cross3d:16x32`` all-frames RMSAE <= 1.5 x its non-silent RMSAE and
  <= 15 deg.

Usage: ``python scripts/cross3d_targets.py [RESULTS_FOLDER] [--grid TASK]`` (default ``results/``);
``--compare A.json B.json`` prints A - B paired over their episodes, pooled and per cell.
``--grid TASK`` checks the grid targets on another grid task of sim-grid's cells (the replica in
``scripts/replica-tasks``, registered through ``DOABENCH_TASK_PATH``) and skips sim-pauses and
sim-fan. A missing
results file, or one of an older task version, is reported as missing (run ``doabench sweep`` or ``doabench run`` first); the exit
status is 0 when every target that could be checked is met and nothing is missing, else 1.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np


def load(folder: Path, task: str, stem: str) -> dict | None:
    """The results of ``stem`` on ``task``, or None when there are none for the task's current
    version (results of an older version are not comparable: other episodes)."""
    from doabench.envs.registry import get_task_spec

    path = folder / f"{task}__{stem}.json"
    if not path.is_file():
        return None
    r = json.loads(path.read_text())
    return r if int(r["task"]["version"]) == get_task_spec(task).version else None


def describe(r: dict) -> str:
    t = r["tracker"]
    weights = (t.get("weights_hash") or "untrained")[:12]
    return f"{t.get('id', t.get('name'))} (weights {weights}, {r['task']['id']} v{r['task']['version']}, " \
           f"{r['task']['episodes_run']} episodes)"


def paired_difference(a: dict, b: dict, cell: str | None = None) -> tuple[float, float, float] | None:
    """``a - b`` over all frames and its paired 95% bootstrap interval over the episodes both ran
    (of one cell, or all); None when either file has no per-episode rows or their episodes differ
    (then only the two runs' own intervals compare them)."""
    from doabench.metrics import paired_difference_ci

    rows = [[e for e in r.get("episodes", []) if cell is None or e["task"] == cell] for r in (a, b)]
    if not rows[0] or [e["seed"] for e in rows[0]] != [e["seed"] for e in rows[1]]:
        return None
    sums = [(np.array([e["rmsae_all"] for e in r]) ** 2 * [e["n_frames"] for e in r], [e["n_frames"] for e in r])
            for r in rows]
    return paired_difference_ci(*sums[0], *sums[1])


def paired(a: dict, b: dict, cell: str | None = None) -> str:
    """:func:`paired_difference` as text; empty when there is none."""
    if (found := paired_difference(a, b, cell)) is None:
        return ""
    d, lo, hi = found
    n = sum(cell is None or e["task"] == cell for e in a["episodes"])
    verdict = "a tie at 95 %" if lo <= 0 <= hi else "significant at 95 %"
    return f"difference {d:+.2f} deg [{lo:+.2f}, {hi:+.2f}] (paired bootstrap over {n} episodes: {verdict})"


def grid_targets(folder: Path, lines: list[str], grid: str = "sim-grid") -> list[str]:
    """Append the table of the grid task ``grid`` to ``lines``; return the missed targets."""
    model, srp, kalman = (load(folder, grid, s) for s in ("cross3d_16x32", "srp-max_16x32", "srp-kalman_32x64"))
    small, maxcnn = load(folder, grid, "cross3d_4x8"), load(folder, grid, "max-cnn1d_64x128")
    missing = [n for n, r in (("cross3d:16x32", model), ("srp-max:16x32", srp), ("srp-kalman:32x64", kalman),
                              ("cross3d:4x8", small), ("max-cnn1d:64x128", maxcnn)) if r is None]
    missed = [f"{grid} results missing for {n}" for n in missing]
    if model is None or srp is None or kalman is None:
        return missed
    lines += [f"{grid}: {describe(model)}", ""]
    pooled = model["summary"]["rmsae_all"]
    lines.append(f"pooled all-frames RMSAE {pooled:.2f} deg (target <= 10): {'yes' if pooled <= 10 else 'NO'}")
    if pooled > 10:
        missed.append(f"pooled {grid} RMSAE {pooled:.2f} > 10 deg")
    lines += ["", "| cell | cross3d:16x32 | srp-max:16x32 | srp-kalman:32x64 | beats srp-max (T60 >= 0.3) "
              "| beats srp-kalman (T60 >= 0.6) |", "|---|---|---|---|---|---|"]
    notes: list[str] = []  # the paired comparison of each cell the model loses
    significant = {"srp-max:16x32": [0, 0], "srp-kalman:32x64": [0, 0]}  # cells won significantly, cells compared
    for cell, c in model["cells"].items():
        a, b, k = c["rmsae_all"], srp["cells"][cell]["rmsae_all"], kalman["cells"][cell]["rmsae_all"]
        t1 = ("yes" if a < b else "NO") if c["t60"] >= 0.3 else "-"
        t2 = ("yes" if a < k else "NO") if c["t60"] >= 0.6 else "-"
        missed += [f"{cell}: {a:.2f} vs srp-max:16x32 {b:.2f}"] if t1 == "NO" else []
        missed += [f"{cell}: {a:.2f} vs srp-kalman:32x64 {k:.2f}"] if t2 == "NO" else []
        lines.append(f"| {cell} | {a:.2f} | {b:.2f} | {k:.2f} | {t1} | {t2} |")
        for name, other, verdict in (("srp-max:16x32", srp, t1), ("srp-kalman:32x64", kalman, t2)):
            if verdict == "NO" and (text := paired(model, other, cell)):
                notes.append(f"{cell}, cross3d:16x32 - {name}: {text}")
            if verdict != "-" and (found := paired_difference(model, other, cell)) is not None:
                significant[name][0] += found[2] < 0
                significant[name][1] += 1
    lines += [""] + notes if notes else []
    lines += [f"paired over each cell's episodes, cross3d:16x32 is significantly lower (95 %) than {name} in "
              f"{won} of the {compared} cells compared" for name, (won, compared) in significant.items() if compared]
    if small is not None and maxcnn is not None:
        a, b = small["summary"]["rmsae_all"], maxcnn["summary"]["rmsae_all"]
        lower = sum(c["rmsae_all"] < maxcnn["cells"][cell]["rmsae_all"] for cell, c in small["cells"].items())
        lines += ["", f"cross3d:4x8 {a:.2f} deg vs max-cnn1d:64x128 {b:.2f} deg (pooled, all frames): "
                      f"{'yes' if a < b else 'NO'}; 4x8 lower in {lower} of {len(small['cells'])} cells; "
                      f"non-silent {small['summary']['rmsae_nonsilent']:.2f} vs "
                      f"{maxcnn['summary']['rmsae_nonsilent']:.2f} deg"]
        if text := paired(small, maxcnn):
            lines.append(f"cross3d:4x8 - max-cnn1d:64x128: {text}")
        missed += [f"cross3d:4x8 {a:.2f} does not beat max-cnn1d:64x128 {b:.2f}"] if a >= b else []
    return missed


def silence_targets(folder: Path, lines: list[str]) -> list[str]:
    missed = []
    lines += ["", "| task | all frames | non-silent | ratio (<= 1.5) | all <= 15 |", "|---|---|---|---|---|"]
    for task in ("sim-pauses", "sim-fan"):
        r = load(folder, task, "cross3d_16x32")
        if r is None:
            missed.append(f"{task} results missing for cross3d:16x32")
            lines.append(f"| {task} | missing | | | |")
            continue
        a, n = r["summary"]["rmsae_all"], r["summary"]["rmsae_nonsilent"]
        ok_ratio, ok_abs = a <= 1.5 * n, a <= 15
        missed += [f"{task}: {a:.2f} > 1.5 x {n:.2f}"] if not ok_ratio else []
        missed += [f"{task}: {a:.2f} > 15 deg"] if not ok_abs else []
        lines.append(f"| {task} | {a:.2f} | {n:.2f} | {a / n:.2f} {'yes' if ok_ratio else 'NO'} "
                     f"| {'yes' if ok_abs else 'NO'} |")
    return missed


def compare(a_path: Path, b_path: Path) -> list[str]:
    """Two results files of the same task (e.g. two weights of one tracker): each one's pooled
    RMSAE, then :func:`paired` over all episodes and per cell."""
    a, b = (json.loads(p.read_text()) for p in (a_path, b_path))
    lines = [f"{p.name}: all {r['summary']['rmsae_all']:.2f} deg, non-silent {r['summary']['rmsae_nonsilent']:.2f} deg"
             for p, r in ((a_path, a), (b_path, b))]
    if not (found := paired(a, b)):
        return lines + ["the two files have no common episodes to pair"]
    lines.append(f"{a_path.name} - {b_path.name}: {found}")
    cells = sorted({e["task"] for e in a["episodes"]})
    if len(cells) > 1:  # a grid: per cell too
        lines += [f"  {cell}: {paired(a, b, cell)}" for cell in cells]
    return lines


def main(argv: list[str]) -> int:
    if argv[:1] == ["--compare"]:
        if len(argv) != 3:
            print("cross3d_targets.py: --compare needs two results files", file=sys.stderr)
            return 2
        try:
            print("\n".join(compare(Path(argv[1]), Path(argv[2]))))
        except (OSError, ValueError, KeyError) as exc:
            print(f"cross3d_targets.py: cannot compare {argv[1]} and {argv[2]}: {exc}", file=sys.stderr)
            return 2
        return 0
    grid = "sim-grid"
    if "--grid" in argv:
        at = argv.index("--grid")
        if at + 1 >= len(argv):
            print("cross3d_targets.py: --grid needs a task id", file=sys.stderr)
            return 2
        grid, argv = argv[at + 1], argv[:at] + argv[at + 2:]
    folder = Path(argv[0]) if argv else Path("results")
    from doabench.envs.registry import get_task_spec
    from doabench.errors import DoabenchError

    try:
        get_task_spec(grid)
    except DoabenchError as exc:  # an unknown --grid task: one line, no traceback
        print(f"cross3d_targets.py: {exc}", file=sys.stderr)
        return 2
    lines: list[str] = []
    missed = grid_targets(folder, lines, grid)
    missed += silence_targets(folder, lines) if grid == "sim-grid" else []
    print("\n".join(lines))
    print("\nall targets met" if not missed else "\nmissed or missing:\n" + "\n".join(f"- {m}" for m in missed))
    return 0 if not missed else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
