"""``doabench list tasks|trackers``."""
from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("list", help="list registered tasks or trackers")
    p.add_argument("what", choices=["tasks", "trackers"])
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    if args.what == "tasks":
        from doabench.envs.registry import available_tasks

        tasks = available_tasks()
        width = max(len(t) for t in tasks)
        for task_id, spec in tasks.items():
            print(f"{task_id:<{width}}  v{spec.version}  {spec.kind:<9} {spec.episodes:>6} ep  {spec.description}")
    else:
        from doabench.trackers.registry import available_trackers

        trackers = available_trackers()
        width = max(len(t) for t in trackers)
        for name, cls in trackers.items():
            doc = (cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else ""
            kind = "causal " if cls.causal else "offline"
            print(f"{name:<{width}}  {kind}  {','.join(cls.features):<18} {doc}")
    return 0
