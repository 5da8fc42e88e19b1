"""``doabench locata-eval --locata-root ROOT --submission DIR --out FILE.json``: the LOCATA challenge's
measures of a submission folder in the challenge's format (doabench's or any other tool's)."""
from __future__ import annotations

import argparse
import warnings
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "locata-eval", help="score a LOCATA submission folder with the challenge's measures",
        description="Score tracks in the LOCATA challenge's submission format (task<N>/recording<R>/<array>/"
                    "source_<k>.txt, as doabench run --locata-submission and the challenge's MATLAB framework write "
                    "them) on every required time stamp: azimuth and inclination errors per voice-active period "
                    "(gated at 30 degrees and ungated), probability of detection, track latency, swap and "
                    "fragmentation rates, false-alarm rates, MOTA and OSPA (p = 1, 1.5, 2, 5; cut-off 30 degrees), "
                    "per recording and averaged per task. Prints the per-task table; writes nothing on bad input.")
    p.add_argument("--locata-root", default=None, help="LOCATA corpus root (default: $DOABENCH_LOCATA)")
    p.add_argument("--submission", required=True, metavar="DIR", help="submission folder holding task<N>/")
    p.add_argument("--split", choices=("dev", "eval"), default="dev", help="corpus split (default dev)")
    p.add_argument("--tasks", metavar="N[,N...]", help="tasks to score (default: the submission's task<N> folders)")
    p.add_argument("--arrays", metavar="A[,A...]",
                   help="arrays to score (default: the array folders of each task in the submission)")
    p.add_argument("--measures", choices=("official", "corrected"), default="official",
                   help="official: as the challenge's released evaluation computes them (default); corrected: as "
                        "the challenge paper defines them (docs/locata.md)")
    p.add_argument("--out", required=True, metavar="FILE.json",
                   help="results JSON; an existing file is replaced only when locata-eval wrote it")
    p.add_argument("--markdown", metavar="FILE.md", help="also write the per-task table as Markdown")
    p.add_argument("--truth-out", metavar="DIR",
                   help="also write the truth scored against: task<N>/recording<R>/<array>/truth_<source>.csv "
                        "(time_s, azimuth, inclination in radians, vad 0/1 on the scored stamps)")
    p.set_defaults(func=main)


def _tasks(text: str | None) -> list[int] | None:
    from doabench.errors import ConfigError

    if not text:
        return None
    try:
        return [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ConfigError(f"--tasks takes task numbers separated by commas, e.g. 1,3,5, not {text!r}") from None


def _arrays(text: str | None) -> list[str] | None:
    return [x.strip() for x in text.split(",") if x.strip()] if text else None


def _check_outputs(args: argparse.Namespace) -> None:
    """Refuse, before any work, an output that would replace a file locata-eval did not write."""
    from doabench.cli.common import check_output_file, check_output_folder
    from doabench.errors import InputError
    from doabench.files import resolve_output
    from doabench.locata.report import markdown_written_by_locata_eval, written_by_locata_eval

    for option, value, ours in (("--out", args.out, written_by_locata_eval),
                                ("--markdown", args.markdown, markdown_written_by_locata_eval)):
        if value is None:
            continue
        check_output_file(value, option=option)
        target = resolve_output(value)
        if target.path is not None and target.path.exists() and not ours(target.path):
            raise InputError(f"{option} {value} exists and was not written by doabench locata-eval; it is never "
                             "replaced (pick another file or remove it)")
    if args.truth_out:
        check_output_folder(args.truth_out, option="--truth-out")
    if args.out and args.markdown and Path(args.out).resolve() == Path(args.markdown).resolve():
        raise InputError("--out and --markdown name the same file")


def _check_truth_out(folder: Path, files: dict[Path, str]) -> None:
    from doabench.errors import InputError
    from doabench.locata.report import truth_file_ours

    for rel in files:
        if not truth_file_ours(folder / rel):
            raise InputError(f"--truth-out {folder}: {folder / rel} exists and was not written by doabench "
                             "locata-eval; it is never replaced")


def main(args: argparse.Namespace) -> int:
    from doabench.files import to_json, write_text
    from doabench.locata.evaluate import evaluate
    from doabench.locata.report import markdown, results, truth_files

    _check_outputs(args)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the measures' warnings are collected and printed below
        evaluation = evaluate(args.locata_root, Path(args.submission), args.split, _tasks(args.tasks),
                              _arrays(args.arrays), args.measures)
    truth = truth_files(evaluation) if args.truth_out else {}
    if args.truth_out:
        _check_truth_out(Path(args.truth_out), truth)
    table = markdown(evaluation)
    write_text(args.out, to_json(results(evaluation)) + "\n")
    if args.markdown:
        write_text(args.markdown, table)
    for rel, text in truth.items():
        write_text(Path(args.truth_out) / rel, text)
    for message in evaluation.warnings:
        warnings.warn(message)
    print(table.split("\n", 2)[2], end="")
    n = len(evaluation.recordings)
    print(f"{n} recording{'s' if n != 1 else ''} scored ({args.measures} measures); wrote {args.out}"
          + (f", {args.markdown}" if args.markdown else "")
          + (f", {len(truth)} truth files under {args.truth_out}" if truth else ""))
    return 0
