"""``doabench list tasks|trackers|weights``."""
from __future__ import annotations

import argparse
import inspect


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("list", help="list registered tasks, trackers or shipped weights",
                       description="List the registered tasks, the trackers, or the shipped weights of the learned "
                                   "trackers by name (--tracker-opt weights=NAME), with the default of each and "
                                   "headline figures from the committed results.")
    p.add_argument("what", choices=["tasks", "trackers", "weights"])
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    if args.what == "tasks":
        from doabench.envs.registry import available_tasks

        tasks = available_tasks()
        width = max(len(t) for t in tasks)
        for task_id, spec in tasks.items():
            print(f"{task_id:<{width}}  v{spec.version}  {spec.kind:<9} {spec.episodes:>6} ep  {spec.description}")
    elif args.what == "weights":
        list_weights()
    else:
        from doabench.trackers.registry import available_trackers

        trackers = available_trackers()
        width = max(len(t) for t in trackers)
        for name, cls in trackers.items():
            doc = summary(cls.__doc__)
            kind = "causal " if cls.causal else "offline"
            print(f"{name:<{width}}  {kind}  {','.join(cls.observation_spec.kind_names):<18} {doc}")
    return 0


def summary(doc: str | None) -> str:
    """A class's description for a listing: its docstring's first paragraph, whole (its first line
    alone can stop mid-sentence), on one line, without reST's literal quotes."""
    first = inspect.cleandoc(doc or "").split("\n\n")[0]
    return " ".join(first.split()).replace("``", "")


#: the tasks whose figures ``list weights`` shows: the default rule's three (docs/models.md)
LISTED_TASKS = ("sim-grid", "sim-walk", "sim-turn")


def list_weights() -> None:
    """One line per shipped weights file: tracker, name (``*``: the default), what it trained on and
    its pooled RMSAE (all frames, deg) on sim-grid, sim-walk and sim-turn, each with its lag or the
    reason it has none (:func:`doabench.cli.weights_text.lag_text`)."""
    from doabench.cli.weights_text import figure_text, lag_legend
    from doabench.trackers.registry import available_trackers

    rows = [w for cls in available_trackers().values() for w in cls.shipped_weights()]
    shown = [(w.get("headline") or {}).get(t) for w in rows for t in LISTED_TASKS]
    header = ("tracker", "name", "trained on", *LISTED_TASKS, "sha256")
    table = [header] + [(w["tracker"], w["name"] + (" *" if w["default"] else ""), str(w.get("task") or "?"),
                         *(figure_text((w.get("headline") or {}).get(t)) for t in LISTED_TASKS),
                         (w.get("sha256") or "?")[:12]) for w in rows]
    widths = [max(len(r[i]) for r in table) for i in range(len(header))]
    for r in table:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip())
    legend = lag_legend(f for f in shown if f)
    print("* the default (no weights option). Figures: pooled RMSAE over all frames [deg] and the tracking lag, "
          "from the committed results (docs/models.md#weights-by-name)" + (f"; {legend}" if legend else "")
          + "; - no complete run. Use --tracker-opt weights=NAME.")
