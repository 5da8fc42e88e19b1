"""``doabench make-dataset --task T --episodes N --features ... --out data.h5``."""
from __future__ import annotations

import argparse

from doabench.cli.common import add_corpus_options, corpus_kwargs


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "make-dataset", help="generate an HDF5 dataset of a task's episodes (features, truth, scenes)",
        description="Simulate N episodes of a task and store their features, per-frame truth, VAD and scene "
                    "parameters in one HDF5 file (schema doabench.dataset/1, docs/hdf5-schema.md). Episode i is the "
                    "same whatever N, --shard or --workers. Killed at any moment, the same command resumes from "
                    "the journal folder <out>.parts/.")
    p.add_argument("--task", required=True, help="task id (doabench list tasks), e.g. sim-train")
    p.add_argument("--episodes", type=int,
                   help="generate N episodes (default: all of the task's), taken as `doabench run --episodes N` "
                        "takes them: on a grid task spread over its cells (the first episode of every cell in turn, "
                        "then the second, ...), else the first N. It says which before it starts")
    p.add_argument("--features", default="srp:16x32",
                   help="comma-separated: srp:NxM (several resolutions allowed; stores srp_max too), gcc, "
                        "spectrogram, audio or a plug-in's feature kind (default srp:16x32)")
    p.add_argument("--shard", help="K/N: only every N-th of the episodes taken, from the K-th on (for cluster array "
                                   "jobs; without --episodes, episodes i with i %% N == K-1)")
    p.add_argument("--workers", type=int,
                   help="simulation processes (default 1); with --engine ray: Ray workers (default: 1 on a local "
                        "instance, every CPU of the cluster with --ray-address)")
    p.add_argument("--engine", choices=["local", "ray"], default="local",
                   help="local (default): this machine's processes; ray: episodes as Ray tasks (needs "
                        "pip install 'doabench[ray]'), see docs/scale-out.md")
    p.add_argument("--ray-address", metavar="ADDR",
                   help="Ray cluster to use with --engine ray (e.g. auto, ray://head:10001); default: start a "
                        "local Ray instance with --workers CPUs")
    p.add_argument("--float16", action="store_true", help="store srp, gcc and spectrogram maps as float16")
    p.add_argument("--sample-vad", action="store_true", help="also store the per-sample VAD (always with audio)")
    p.add_argument("--compression", choices=["gzip", "lzf", "none"], default="gzip",
                   help="chunk compression (default gzip level 4 with shuffle)")
    p.add_argument("--delays", choices=["nearest", "exact"], default="nearest", help="SRP-PHAT delay mode")
    p.add_argument("--out", required=True, help="output file, e.g. data.h5")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_corpus_options(p)
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from doabench.datasets.generate import make_dataset
    from doabench.datasets.schema import parse_shard
    from doabench.envs.registry import get_task_spec

    from doabench.errors import ConfigError

    options = corpus_kwargs(args)
    backend = options.pop("backend")
    if args.ray_address and args.engine != "ray":
        raise ConfigError("--ray-address needs --engine ray")
    workers = args.workers
    if workers is None and not (args.engine == "ray" and args.ray_address):
        workers = 1
    from doabench.cli.common import set_interrupt_note

    set_interrupt_note(args, lambda: _kept(args))
    task = get_task_spec(args.task)  # looked up once, here; the spec goes on
    result = make_dataset(task, args.out, episodes=args.episodes, features=args.features,
                          shard=parse_shard(args.shard), workers=workers, float16=args.float16,
                          sample_vad=args.sample_vad, compression=args.compression, delays=args.delays,
                          device=args.device, backend=backend, progress=not args.quiet, engine=args.engine,
                          ray_address=args.ray_address, say=print, **options)
    size = result.size
    if result.already_complete:
        print(f"{result.path} is already complete ({result.n_episodes} episodes); nothing to do")
        return 0
    resumed = f", {result.resumed} from an earlier run" if result.resumed else ""
    print(f"wrote {result.path}: {result.n_episodes} episodes{resumed}, {size / result.n_episodes / 1e6:.2f} MB per "
          f"episode, {result.episodes_per_minute:.1f} episodes/min")
    return 0


def _kept(args: argparse.Namespace) -> str:
    """The stop message: the finished episodes the journal folder keeps, and how to resume."""
    from doabench.cli.common import command_line
    from doabench.datasets.generate import parts_dir
    from doabench.files import resolve_output

    if resolve_output(args.out).stream:
        return f"nothing was written (a stream output keeps no journal); start it again with: {command_line(args)}"
    folder = parts_dir(args.out)
    n = len(list(folder.glob("[0-9]*.h5"))) if folder.is_dir() else 0
    if not n:
        return f"no episode had finished, nothing was kept; start it again with: {command_line(args)}"
    return (f"{n} finished episode{'s' if n > 1 else ''} kept in {folder}; resume with the same command: "
            f"{command_line(args)}")
