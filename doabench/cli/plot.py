"""``doabench plot``: the paper's figures from results files, tasks and training logs (PNG + PDF)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from doabench.cli.common import add_corpus_options, corpus_kwargs


def _corpus_options(p: argparse.ArgumentParser) -> None:
    add_corpus_options(p, only=("librispeech", "locata_root", "split", "backend"))


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plot", help="plot results, episodes, SRP maps and training curves",
                       description="Figures as PNG and PDF (written atomically), named by --out "
                                   "(fig -> fig.png and fig.pdf).")
    kinds = p.add_subparsers(dest="figure", metavar="FIGURE", required=True)

    q = kinds.add_parser("rmsae-vs-t60", help="RMSAE versus T60 per SNR from grid results (paper Figs. 6, 8)")
    q.add_argument("results", nargs="+",
                   help="results JSON files of a grid task or of its cells (one line per tracker configuration: "
                        "the per-cell files of one tracker join into one line)")
    q.add_argument("--snr", type=float, action="append",
                   help="SNR panel(s) in dB (repeatable; default: every SNR in the results)")
    q.add_argument("--metric", choices=["rmsae_all", "rmsae_nonsilent"], default="rmsae_nonsilent",
                   help="rmsae_nonsilent (Fig. 6, default) or rmsae_all (Fig. 8)")
    q.add_argument("--title", help="figure title")
    q.add_argument("--out", default="rmsae-vs-t60", help="output path without extension (default: rmsae-vs-t60)")
    q.set_defaults(func=rmsae_vs_t60)

    q = kinds.add_parser("rmsae-vs-speed",
                         help="RMSAE of voice-active frames per angular-speed band of the truth (<5, 5-15, 15-30, "
                              ">30 deg/s)")
    q.add_argument("results", nargs="+",
                   help="results JSON files with summary.speed_bands (one line per file; runs of several tasks "
                        "are told apart by task in the legend)")
    q.add_argument("--title", help="figure title")
    q.add_argument("--out", default="rmsae-vs-speed", help="output path without extension (default: rmsae-vs-speed)")
    q.set_defaults(func=rmsae_vs_speed)

    q = kinds.add_parser("episode", help="elevation/azimuth over time of one episode (paper Fig. 7)")
    q.add_argument("results", nargs="+",
                   help="results JSON file(s) with per-frame estimates; several files (runs of the same task) "
                        "are compared in one figure, one line per run")
    q.add_argument("--episode", type=int, required=True, help="episode index within the task")
    q.add_argument("--no-render", action="store_true",
                   help="do not re-render the episode: no SRP maxima; silent frames are still shaded, from the "
                        "VAD stored in the results file (files without one: no shading)")
    q.add_argument("--resolution", help="SRP resolution of the maxima (default: the run's, else 32x64)")
    q.add_argument("--out", help="output path without extension (default: <task>-episode-<i>)")
    _corpus_options(q)
    q.set_defaults(func=episode)

    q = kinds.add_parser("maps", help="SRP-PHAT maps of one frame at several resolutions (paper Figs. 1, 2)")
    q.add_argument("--task", required=True, help="task id (doabench list tasks)")
    q.add_argument("--episode", type=int, default=0, help="episode index (default 0)")
    q.add_argument("--frame", type=int, required=True, help="frame index within the episode")
    q.add_argument("--resolutions", default="4x8,8x16,16x32,32x64", help="comma-separated N_THETAxN_PHI list")
    q.add_argument("--delays", choices=["nearest", "exact"], default="nearest", help="SRP-PHAT delay mode")
    q.add_argument("--out", help="output path without extension (default: <task>-maps-<episode>-<frame>)")
    _corpus_options(q)
    q.set_defaults(func=maps)

    q = kinds.add_parser("conventions", help="array frame and SRP grid conventions (docs/concepts.md figure)")
    q.add_argument("--array", default="nao", help="array name or JSON/YAML file (default nao)")
    q.add_argument("--resolution", default="8x16", help="SRP grid to draw (default 8x16)")
    q.add_argument("--out", default="conventions", help="output path without extension (default: conventions)")
    q.set_defaults(func=conventions)

    q = kinds.add_parser("training", help="training curves from doabench train log.csv files")
    q.add_argument("logs", nargs="+", help="runs/NAME/log.csv (several runs: one colour and marker each)")
    q.add_argument("--out", default="training", help="output path without extension (default: training)")
    q.set_defaults(func=training)


def _done(paths) -> int:
    for path in paths:
        print(f"wrote {path}")
    return 0


def rmsae_vs_t60(args: argparse.Namespace) -> int:
    from doabench.results.schema import load_results
    from doabench.reporting.plots import plot_rmsae_vs_t60

    runs = [load_results(path) for path in args.results]
    return _done(plot_rmsae_vs_t60(runs, args.out, args.snr, args.metric, args.title))


def rmsae_vs_speed(args: argparse.Namespace) -> int:
    from doabench.results.schema import load_results
    from doabench.reporting.plots import plot_rmsae_vs_speed

    runs = [load_results(path) for path in args.results]
    return _done(plot_rmsae_vs_speed(runs, args.out, args.title, sources=args.results))


def episode(args: argparse.Namespace) -> int:
    from doabench.geometry import parse_resolution
    from doabench.results.identity import results_grid
    from doabench.results.schema import load_results
    from doabench.reporting.plots import episode_frames, plot_episode, render_episode

    import numpy as np

    runs = [load_results(path) for path in args.results]
    results, others = runs[0], runs[1:]
    task = results["task"]["id"]
    stored = episode_frames(results, args.episode)
    for path, other in zip(args.results[1:], others):
        from doabench.errors import InputError

        if other["task"]["id"] != task:
            raise InputError(f"{path} is a run of task {other['task']['id']!r}, not {task!r}: compare runs of one task")
        theirs = episode_frames(other, args.episode)
        if len(theirs["truth"]) != len(stored["truth"]) or not np.allclose(theirs["truth"], stored["truth"], atol=1e-4):
            raise InputError(f"{path}: episode {args.episode} has another truth than in {args.results[0]} "
                             "(another task version or frame spec?)")
    maxima = None
    vad = stored["vad"]  # results files written since the VAD was kept per frame have it
    label = "SRP-PHAT maximum"
    if not args.no_render:
        from doabench.features.functional import map_argmax_directions

        import torch

        res = parse_resolution(args.resolution) if args.resolution else (
            results_grid(results) or (32, 64))
        _, srp, truth, array = render_episode(task, args.episode, res, **corpus_kwargs(args))
        if len(truth["directions"]) != len(stored["truth"]) or not np.allclose(
                truth["directions"], stored["truth"], atol=1e-5):
            # The episode is re-created from its seed; a mismatch means the code or corpus changed since the run.
            print(f"doabench plot: warning: the re-rendered episode {args.episode} differs from the truth stored in "
                  f"{args.results[0]}; the maxima and silent frames may not belong to this run", file=sys.stderr)
        vad = np.asarray(truth["vad"], bool)
        directions = map_argmax_directions(torch.as_tensor(srp), planar=array.planar).numpy()
        maxima = np.where(vad[:, None], directions, np.nan)  # silent frames have no map (zeros)
        label = f"SRP-PHAT {res[0]}x{res[1]} maximum"
    out = args.out or f"{task}-episode-{args.episode}"
    return _done(plot_episode(results, args.episode, out, maxima=maxima, vad=vad, maxima_label=label,
                              others=others))


def maps(args: argparse.Namespace) -> int:
    from doabench.geometry import parse_resolution
    from doabench.reporting.plots import plot_maps, srp_maps

    resolutions = [parse_resolution(r.strip()) for r in args.resolutions.split(",") if r.strip()]
    if not resolutions:
        from doabench.errors import InputError

        raise InputError("--resolutions needs at least one N_THETAxN_PHI value")
    found = srp_maps(args.task, args.episode, args.frame, resolutions, delays=args.delays,
                     **corpus_kwargs(args))
    if not found["active"]:
        print(f"doabench plot: warning: frame {args.frame} is silent (its maps are zero); pick a voice-active frame",
              file=sys.stderr)
    meta = found["episode"].metadata or {}
    scene = meta.get("scene")
    if not isinstance(scene, dict):
        scene = {}
    bits = [f"{args.task} episode {args.episode}, frame {args.frame}"]
    t60 = scene.get("t60")
    if t60 is None and meta.get("task"):
        from doabench.envs.registry import get_task_spec

        t60 = (get_task_spec(meta["task"]).params.get("cell") or {}).get("t60")  # grid cells fix T60
    if t60 is not None:
        bits.append(f"T60 {t60:.2g} s")
    if scene.get("snr_db") is not None:
        bits.append(f"SNR {scene['snr_db']:.3g} dB")
    out = args.out or f"{args.task}-maps-{args.episode}-{args.frame}"
    return _done(plot_maps(found["maps"], found["direction"], out, planar=bool(found["array"].planar),
                           title=", ".join(bits)))


def training(args: argparse.Namespace) -> int:
    from doabench.reporting.plots import plot_training, read_training_log

    logs = {}
    for path in args.logs:
        p = Path(path)
        name = p.parent.name if p.name == "log.csv" and p.parent.name else p.stem
        while name in logs:
            name += "'"
        logs[name] = read_training_log(p)
    return _done(plot_training(logs, args.out))


def conventions(args: argparse.Namespace) -> int:
    from doabench.arrays import get_array
    from doabench.geometry import parse_resolution
    from doabench.reporting.plots import plot_conventions

    return _done(plot_conventions(get_array(args.array), parse_resolution(args.resolution), args.out))
