"""``doabench describe --tracker X`` / ``--task Y``: JSON description."""
from __future__ import annotations

import argparse

from doabench.cli.common import add_tracker_options


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("describe", help="print a tracker's or a task's description as JSON")
    add_tracker_options(p, required=False)
    p.add_argument("--task", help="describe a task instead")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from doabench.errors import ConfigError
    from doabench.files import to_json

    if bool(args.tracker) == bool(args.task):
        raise ConfigError("give exactly one of --tracker or --task")
    if args.task:
        from doabench.envs.registry import get_task_spec

        spec = get_task_spec(args.task)
        print(to_json({**spec.to_dict(), "gym_id": spec.gym_id, "source_file": spec.source_file}))
        return 0
    from doabench.trackers.registry import make_tracker, parse_options

    tracker = make_tracker(args.tracker, **parse_options(args.tracker_opt))
    print(to_json(tracker.describe()))
    return 0
