"""Maintainers: does a retrained Cross3D meet the moving-talker ship targets (docs/results.md)?

The targets a model must meet before it becomes the default ``cross3d``:

* ``sim-walk`` and ``sim-turn``: pooled lag <= 0.3 s, and in every T60 band an RMSAE (all frames
  and voice-active) below both ``srp-max:32x64`` and ``srp-kalman-cv:32x64`` (the constant-velocity
  classical tracker), on the same episodes;
* ``sim-grid``, ``sim-pauses`` and ``sim-fan``: no significant loss against the paper-recipe weights
  (``cross3d:16x32``, ``weights=paper``; ``--reference-stem``): the 95 % upper bound of the paired
  difference (candidate minus reference, all frames, ``doabench compare``'s bootstrap) at most +0.3 deg.
  ``sim-pauses`` (v3, 120 episodes) and ``sim-fan`` (v3, 240 episodes) give a network close to the
  reference an interval of about +-0.2 deg, so a level one can pass (a second paper-recipe network,
  ``weights=paper-v3``: -0.02 [-0.19, +0.18] on ``sim-pauses``, +0.09 [-0.11, +0.32] on ``sim-fan``). Where an interval's upper half is
  still wider than the allowed loss (a network that differs more from the reference), a candidate
  level with it fails too; the line says how much better one must be on those episodes.

The candidate's results come from one sweep (per-frame estimates are not needed), e.g.

    DOABENCH_EPISODE_CACHE=runs/episode-cache doabench sweep --trackers cross3d:16x32 \\
        --tracker-opt weights=moving \\
        --tasks sim-walk,sim-turn,sim-grid,sim-pauses,sim-fan --no-frames --out runs/ship-check
    python scripts/ship_check_moving.py runs/ship-check

and are checked against the committed results of the classical trackers and of the paper-recipe reference in
``results/``. Prints one line per check and exits 0 when every one holds, 1 when one fails, 2 when
a results file is missing.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from doabench.reporting.compare import compare
from doabench.reporting.pairing import Run, load_run

ROOT = Path(__file__).resolve().parents[1]
MOVING_TASKS = ("sim-walk", "sim-turn")
STATIC_TASKS = ("sim-grid", "sim-pauses", "sim-fan")
CLASSICAL = ("srp-max_32x64", "srp-kalman-cv_32x64")
MAX_LAG_S = 0.3
MAX_LOSS_DEG = 0.3


def find(folder: Path, task: str, stem: str) -> Path:
    """The results file of ``stem`` (``cross3d_16x32``, ``srp-max_32x64``) on ``task`` in ``folder``."""
    matches = sorted(p for p in folder.glob(f"{task}__{stem}*.json"))
    if not matches:
        raise FileNotFoundError(f"no results of {stem} on {task} in {folder}")
    return matches[0]


def exact(folder: Path, task: str, stem: str) -> Path:
    """The results file ``{task}__{stem}.json`` in ``folder`` (no other options in its name)."""
    path = folder / f"{task}__{stem}.json"
    if not path.is_file():
        raise FileNotFoundError(f"no results file {path.name} in {folder}")
    return path


def band_rmsae(run: Run, episodes: set[int] | None = None) -> dict[float, tuple[float, float]]:
    """Per T60: the RMSAE pooled over the band's frames, all and voice-active (from the episode rows),
    over ``episodes`` only when given (the candidate's, when it ran part of the task)."""
    sums: dict[float, list[float]] = {}
    for row in run.rows:
        if episodes is not None and int(row["episode"]) not in episodes:
            continue
        s = sums.setdefault(float(row["t60"]), [0.0, 0.0, 0.0, 0.0])
        s[0] += row["n_frames"] * row["rmsae_all"] ** 2
        s[1] += row["n_frames"]
        if row["n_nonsilent"]:
            s[2] += row["n_nonsilent"] * row["rmsae_nonsilent"] ** 2
            s[3] += row["n_nonsilent"]
    return {t60: (math.sqrt(s[0] / s[1]), math.sqrt(s[2] / s[3]) if s[3] else math.nan)
            for t60, s in sorted(sums.items())}


def too_few_episodes(diff: float, high: float, n_episodes: int) -> str:
    """What a static check's interval lets pass: where its upper half is wider than the allowed
    loss, a candidate level with the reference fails too, so the line says how much better one must
    be on these episodes (the interval's width taken as it is; '' where a level candidate passes)."""
    half = high - diff
    if half <= MAX_LOSS_DEG:
        return ""
    return (f"; with {n_episodes} episodes the interval reaches {half:.2f} deg above the difference, so only a "
            f"candidate about {half - MAX_LOSS_DEG:.2f} deg better than the reference passes")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("candidate", type=Path, help="folder of the candidate's results (the sweep's --out)")
    ap.add_argument("--baseline", type=Path, default=ROOT / "results",
                    help="folder of the classical trackers' and the paper-recipe reference's results (default: results/)")
    ap.add_argument("--stem", default="cross3d_16x32", help="results-file stem of the candidate (its files' names "
                    "start with it)")
    ap.add_argument("--reference-stem", default="cross3d_16x32__paper",
                    help="the exact results-file stem the static checks compare with (default: the paper-recipe "
                         "cross3d:16x32, weights=paper; any candidate's resolution is compared with it)")
    args = ap.parse_args(argv)
    checks: list[tuple[bool, str]] = []
    try:
        for task in MOVING_TASKS:
            cand = load_run(find(args.candidate, task, args.stem))
            episodes = {int(r["episode"]) for r in cand.rows}
            if not cand.task.get("complete", True):
                print(f"note: the candidate ran {len(episodes)} of {cand.task.get('episodes_total')} {task} episodes: "
                      "the classical trackers are scored on those; a check for direction, not for shipping")
            lag = cand.results["summary"].get("lag_s")
            checks.append((lag is not None and lag <= MAX_LAG_S, f"{task}: pooled lag {lag} s (at most {MAX_LAG_S})"))
            mine = band_rmsae(cand)
            for other in CLASSICAL:
                theirs = band_rmsae(load_run(find(args.baseline, task, other)), episodes)
                for t60, (all_c, voice_c) in mine.items():
                    all_o, voice_o = theirs[t60]
                    checks.append((all_c < all_o and voice_c < voice_o,
                                   f"{task} T60 {t60:g} s: {all_c:.2f} / {voice_c:.2f} deg against {other} "
                                   f"{all_o:.2f} / {voice_o:.2f} (all / voice-active, below both)"))
        for task in STATIC_TASKS:
            comparison = compare(load_run(find(args.candidate, task, args.stem)),
                                 load_run(exact(args.baseline, task, args.reference_stem)), only=["rmsae_all"])
            row = comparison.pooled[0]
            checks.append((row.high <= MAX_LOSS_DEG,
                           f"{task}: {row.a:.2f} against {row.b:.2f} deg, paired difference {row.diff:+.2f} "
                           f"[{row.low:+.2f}, {row.high:+.2f}] (upper bound at most +{MAX_LOSS_DEG})"
                           + too_few_episodes(row.diff, row.high, row.n_episodes)))
    except FileNotFoundError as exc:
        print(f"ship_check_moving: {exc}", file=sys.stderr)
        return 2
    for ok, text in checks:
        print(("pass  " if ok else "FAIL  ") + text)
    failed = sum(not ok for ok, _ in checks)
    print(f"{len(checks) - failed} of {len(checks)} checks pass" + ("" if failed else ": the candidate may ship"))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
