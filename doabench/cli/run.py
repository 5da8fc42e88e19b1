"""``doabench run --tracker X --task Y``: run, score, print a table, write results."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from doabench.cli.common import add_corpus_options, add_threads_option, add_tracker_options, corpus_kwargs, use_threads

#: where results go without --out: under the git-ignored runs/, never the committed results/
DEFAULT_OUT = "runs/results"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run a tracker on a task and score it",
                       description="Run a tracker on a task, print the scores and write a results JSON and CSV. "
                                   "An interrupted run resumes from its .partial.jsonl file when run again.")
    add_tracker_options(p)
    p.add_argument("--task", required=True, help="task id (doabench list tasks)")
    p.add_argument("--episodes", type=int,
                   help="run only N episodes: on a grid task spread over its cells (the first episode of every "
                        "cell in turn, then the second, ...), else the first N. A partial run is ranked apart "
                        "from complete runs on the leaderboards")
    p.add_argument("--cells", metavar="IDS",
                   help="grid tasks: run only these cells (comma-separated cell task ids, doabench list tasks); "
                        "with --episodes, N episodes spread over them")
    p.add_argument("--delays", choices=["nearest", "exact"], default=None,
                   help="SRP-PHAT delay mode (default: the one the tracker's weights were trained on, else nearest; "
                        "another is used on purpose and the results record the trained one)")
    p.add_argument("--out", default=DEFAULT_OUT,
                   help=f"folder for results files (default: {DEFAULT_OUT}/, git-ignored; the committed results/ "
                        "change only through `make update-demo-results` or an explicit --out results)")
    p.add_argument("--replace", "--overwrite", dest="overwrite", action="store_true",
                   help="replace the results file of this run's name whatever it holds. Without it a file of "
                        "another configuration (task version, weights, options), or one holding episodes this run "
                        "does not take (4 episodes, then a run of --episodes 2), is refused before the work; a run "
                        "of the same episodes, or of those and more, replaces it. --overwrite is its older name")
    p.add_argument("--no-frames", action="store_true", help="do not store per-frame estimates in the JSON")
    p.add_argument("--locata-submission", metavar="DIR",
                   help="LOCATA tasks: also write the estimates in the challenge's submission format, "
                        "DIR/task<N>/recording<R>/<array>/source_1.txt (each required time stamp takes the latest "
                        "estimate; NaN before the first), for doabench locata-eval or the challenge's own evaluation")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_threads_option(p)
    add_corpus_options(p)
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from doabench.cli.common import check_output_folder, make_checked_tracker, set_interrupt_note
    from doabench.envs.registry import get_task_spec
    from doabench.envs.sources import kind_options, task_kind
    from doabench.errors import ConfigError
    from doabench.files import write_text
    from doabench.results.writer import (alias_files, check_overwrite, coverage_lines, format_summary, weights_line,
                                         write_results)
    from doabench.runner import RunSpec
    from doabench.envs.selection import parse_cells, select_episodes
    from doabench.trackers.registry import parse_options, tracker_ref

    check_output_folder(args.out)  # before the work, not after it
    use_threads(args)
    options = parse_options(args.tracker_opt)
    ref = tracker_ref(args.tracker)  # the ids are looked up once, here, and passed on as values
    task = get_task_spec(args.task)
    tracker = make_checked_tracker(ref, options)  # before any file or folder is made
    # One model, one name: aliases (cross3d = cross3d:16x32, default-valued options) resolve to
    # the canonical id and options before the file is named (RunSpec.build).
    spec, tracker = RunSpec.build(ref, task, options, args.delays, instance=tracker, env_options=corpus_kwargs(args))
    if spec.trained_delays is not None:
        print(f"note: {spec.tracker} was trained on {spec.trained_delays} SRP delays; running with --delays "
              f"{spec.delays} as asked (the results record both)", file=sys.stderr)
    if args.vad and "vad" not in kind_options(task_kind(task.kind, task.id)):
        raise ConfigError(f"--vad applies to LOCATA tasks; task {spec.task!r} is {task.kind} (its VAD is the scene's)")
    out = Path(args.out)
    created = [p for p in [out, *out.parents] if not p.exists()]
    # Refused before the work: a file of another configuration under this name, or one holding episodes
    # this run does not take (never replaced silently; the episodes are those of the file's task size).
    cells = parse_cells(args.cells)
    check_overwrite(spec.results_path(out), spec.configuration(), args.overwrite,
                    episodes=lambda total: select_episodes(task, total, args.episodes, cells)[0])
    if args.locata_submission:
        _check_submission_option(args, task.kind)
    partial = spec.journal_path(out)
    if spec.weights_hash or tracker.describe().get("trained") is False:  # which weights, before the work
        print(f"doabench run: {spec.tracker} on {spec.task}; {weights_line(tracker.describe())}", file=sys.stderr)
    set_interrupt_note(args, lambda: _kept(args, partial))
    try:
        # a second run with the same --out, task and tracker is refused (the journal's lock)
        results = spec.execute(tracker, out, episodes=args.episodes, cells=cells,
                               device=args.device, progress=not args.quiet, keep_frames=not args.no_frames,
                               **corpus_kwargs(args))
        submission = _submission(args, results)  # built (and refused) before anything is written
        json_path, csv_path = write_results(results, out, overwrite=args.overwrite)
        for path, text in submission.items():
            write_text(path, text)
        aliases = alias_files(results, out)
        for old in aliases:  # the same configuration written under an alias of the id
            old.unlink(missing_ok=True)
            old.with_suffix(".csv").unlink(missing_ok=True)
        partial.unlink(missing_ok=True)
    except BaseException:
        for folder in created:  # folders this run made and left empty go again
            try:
                folder.rmdir()
            except OSError:
                break
        raise
    print(format_summary(results))
    print("\n".join(coverage_lines(results, json_path)))
    if results.get("locata"):
        from doabench.locata.report import run_lines

        print(run_lines(results["locata"]))
    print(f"wrote {json_path} and {csv_path}")
    if submission:
        print(f"wrote the LOCATA submission of {len(submission) // 2} recording(s) under {args.locata_submission}")
    if aliases:
        print(f"replaced {', '.join(str(p) for p in aliases)} (the same configuration under an alias of {spec.tracker})")
    return 0


def _kept(args: argparse.Namespace, partial: Path) -> str:
    """The stop message: the finished episodes the journal keeps, and the command that resumes."""
    from doabench.cli.common import command_line
    from doabench.runner.journal import journal_count

    n = journal_count(partial)
    if not n:
        return f"no episode had finished, nothing was kept; start it again with: {command_line(args)}"
    return (f"{n} finished episode{'s' if n > 1 else ''} kept in {partial}; resume with the same command: "
            f"{command_line(args)}")


def _check_submission_option(args: argparse.Namespace, kind: str) -> None:
    """``--locata-submission`` needs a LOCATA task, the per-frame estimates and a folder to write."""
    from doabench.cli.common import check_output_folder
    from doabench.errors import ConfigError

    if kind != "locata":
        raise ConfigError(f"--locata-submission applies to LOCATA tasks; task {args.task!r} is {kind}")
    if args.no_frames:
        raise ConfigError("--locata-submission needs the per-frame estimates: leave out --no-frames")
    check_output_folder(args.locata_submission, option="--locata-submission")


def _submission(args: argparse.Namespace, results: dict) -> dict[Path, str]:
    """The ``--locata-submission`` files (path -> text); a track file there that doabench did not
    write (another tool's, with more tracks) is refused rather than mixed with this run's."""
    from doabench.errors import ConfigError
    from doabench.locata.run_scores import submission_from_results

    if not args.locata_submission:
        return {}
    files = submission_from_results(results, Path(args.locata_submission))
    for folder in {p.parent for p in files}:
        foreign = sorted(p.name for p in folder.glob("source_*.txt") if p.name != "source_1.txt") if folder.is_dir() else []
        if foreign:
            raise ConfigError(f"--locata-submission: {folder} already holds {', '.join(foreign)}; a one-track run "
                              "would mix with those tracks (pick another folder)")
    return files
