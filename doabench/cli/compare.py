"""``doabench compare A.json B.json [C.json ...]``: is run A better than B (and C ...) on the same episodes?"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "compare", help="paired comparison of results files on the episodes they share",
        description="Compare the first results file with each other one over the episodes both ran (same task, "
                    "task version and seeds): the difference of every summary metric (RMSAE all frames and "
                    "voice-active, MAE, median, p90, shares within 5-30°, azimuth MAE, tracking lag, RMSAE by "
                    "angular speed, where the files carry them), pooled and per grid cell, with a 95% interval "
                    "from a paired bootstrap over episodes (stratified by cell where every cell holds at least 5 "
                    "paired episodes, else drawn across the task) and a verdict: better, worse or "
                    "no significant difference; 'too few episodes' instead where fewer than --min-episodes paired "
                    "episodes contribute to a line (column n). Markdown on stdout.")
    p.add_argument("results", nargs="+", metavar="RESULTS.json",
                   help="results files of one task: the first is compared with each of the others")
    p.add_argument("--csv", metavar="FILE", help="also write every row (pooled and per cell) as CSV")
    p.add_argument("--plot", metavar="OUT", help="forest plot of the per-cell differences: OUT.png and OUT.pdf")
    p.add_argument("--silence", action="store_true",
                   help="break the error down by frames since the last voice-active frame (before and after the "
                        "first voice too), with the hold-the-truth oracle; needs per-frame estimates. With one "
                        "results file: only this breakdown")
    p.add_argument("--hold", metavar="N[,N...]",
                   help="also compare the RMSAE over all frames with the estimates held after N silent frames "
                        "(the learned trackers' hold rule); needs per-frame estimates")
    p.add_argument("--cell-metrics", default="rmsae_all,rmsae_nonsilent,lag_s", metavar="LIST",
                   help="metrics shown per cell in the Markdown (default rmsae_all,rmsae_nonsilent,lag_s; "
                        "the CSV has them all)")
    p.add_argument("--by-seed", action="store_true",
                   help="pair the episodes of two tasks that render the same scenes (same scene seeds) differently, "
                        "e.g. sim-walk and sim-walk-pra (builtin against pyroomacoustics)")
    p.add_argument("--min-episodes", type=int, default=5, metavar="N",
                   help="paired episodes that must contribute to a line (frames of it in both runs) for a verdict; "
                        "below it the line says 'too few episodes' (default 5)")
    p.add_argument("--resamples", type=int, default=2000, help="bootstrap resamples (default 2000)")
    p.add_argument("--seed", type=int, default=0, help="bootstrap seed (default 0)")
    p.set_defaults(func=main)


def _holds(text: str | None) -> list[int]:
    from doabench.errors import ConfigError

    if not text:
        return []
    try:
        holds = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ConfigError(f"--hold takes whole numbers of frames separated by commas, not {text!r}") from None
    if any(h < 1 for h in holds):
        raise ConfigError(f"--hold frame counts must be at least 1, got {text!r}")
    return holds


def main(args: argparse.Namespace) -> int:
    from doabench.cli.common import check_output_file
    from doabench.errors import ConfigError, InputError
    from doabench.files import write_text
    from doabench.reporting.compare import compare
    from doabench.reporting.compare_report import csv_text, markdown, plot_forest
    from doabench.reporting.pairing import distinct_labels, frames_by_episode, load_run
    from doabench.reporting.silence import held_rmsae, hold_the_truth, silence_breakdown

    holds = _holds(args.hold)
    if args.resamples < 100:
        raise ConfigError(f"--resamples must be at least 100, got {args.resamples}")
    if args.min_episodes < 2:  # one episode gives a bootstrap interval of no width
        raise ConfigError(f"--min-episodes must be at least 2, got {args.min_episodes}")
    paths = [Path(p) for p in args.results]
    if len(paths) < 2 and not args.silence:
        raise InputError("compare needs two or more results files (one is enough with --silence)")
    if args.csv:
        check_output_file(args.csv, paths, "--csv")
    if args.plot:
        for out in cmp_output_paths(args.plot):
            check_output_file(out, paths, "--plot")
    runs = [load_run(p) for p in paths]
    # the first file again (a glob that matches it too) is not compared with itself
    first, others = runs[0], [r for r in runs[1:] if r.path.resolve() != runs[0].path.resolve()]
    if not others and not args.silence:
        raise InputError(f"nothing to compare {first.path} with: give another results file of the same task")
    distinct_labels([first, *others])
    comparisons = [compare(first, other, args.silence, holds, args.resamples, args.seed, by_seed=args.by_seed,
                               min_episodes=args.min_episodes) for other in others]
    breakdowns = []
    if args.silence:
        if comparisons:  # each run over the episodes it shares with the first (all compared runs share them)
            compared = [(first, comparisons[0].pairing.frames_a)] + [(c.pairing.b, c.pairing.frames_b)
                                                                      for c in comparisons]
            # none is dropped: with --silence, compare() refuses a run without per-frame estimates
            pairs = [(run, run_frames) for run, run_frames in compared if run_frames is not None]
        else:
            frames = frames_by_episode(first)
            if frames is None:
                raise InputError(f"--silence needs per-frame estimates, which {first.path} lacks (written with "
                                 "--no-frames); run it again without --no-frames")
            pairs = [(first, [frames[k] for k in sorted(frames)])]
        breakdowns = [(run, silence_breakdown(frames), hold_the_truth(frames),
                       {h: held_rmsae(frames, h) for h in holds}) for run, frames in pairs]
    cell_metrics = [m.strip() for m in args.cell_metrics.split(",") if m.strip()]
    sys.stdout.write(markdown(comparisons, cell_metrics, breakdowns, args.resamples))
    if args.csv:
        if not comparisons:
            raise InputError("--csv needs two or more results files to compare")
        write_text(args.csv, csv_text(comparisons))
        print(f"wrote {args.csv}", file=sys.stderr)
    if args.plot:
        if not comparisons:
            raise InputError("--plot needs two or more results files to compare")
        for path in plot_forest(comparisons, args.plot):
            print(f"wrote {path}", file=sys.stderr)
    return 0


def cmp_output_paths(out: str) -> list[Path]:
    """The PNG and PDF a ``--plot OUT`` writes."""
    from doabench.reporting.plots import output_paths

    return output_paths(out)
