"""``doabench dataset info FILE`` and ``doabench dataset merge A B ... --out FILE``."""
from __future__ import annotations

import argparse
import json
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("dataset", help="inspect or merge dataset files made by make-dataset",
                       description="Inspect (info) or join shards (merge) of doabench dataset files.")
    dsub = p.add_subparsers(dest="dataset_command", metavar="ACTION")
    info = dsub.add_parser("info", help="summarise a dataset file (task, episodes, features, sizes, config)")
    info.add_argument("path", help="dataset file (or the output of an unfinished make-dataset)")
    info.add_argument("--json", action="store_true", help="print the summary as JSON")
    info.set_defaults(func=main_info)
    merge = dsub.add_parser("merge", help="join shards of one dataset into one file")
    merge.add_argument("inputs", nargs="+", help="dataset files (shards of the same task and config)")
    merge.add_argument("--out", required=True, help="merged output file")
    merge.set_defaults(func=main_merge)
    p.set_defaults(func=lambda args: (p.print_help(), 1)[1])


def _mb(n: float | None) -> str:
    return "-" if n is None else f"{n / 1e6:.3f} MB"


def format_info(info: dict) -> str:
    cfg = info["config"]
    lines = [
        f"file:      {info['path']} ({_mb(info['file_bytes'])}, schema {info['schema']})",
        f"task:      {info['task']} v{info['task_version']}  backend {info['backend']}  created {info['created']}",
        f"episodes:  {info['episodes_complete']} complete / {info['episodes_requested']} requested"
        + (f"  (missing: {info['episodes_missing'][:10]}{' ...' if len(info['episodes_missing']) > 10 else ''})"
           if info["episodes_missing"] else "")
        + (f"  [{info['incomplete_groups']} incomplete groups ignored]" if info["incomplete_groups"] else ""),
        f"per episode: {_mb(info['bytes_per_episode'])}",
        f"frames:    window {info['frames']['window']}, hop {info['frames']['hop']}, fs {info['frames']['fs']}",
        f"features:  {', '.join(info['features']) or '-'}",
        "arrays (first episode):",
    ]
    for path, a in sorted(info["arrays"].items()):
        described = f"  [{a['units']}] {a['axes']}" if a.get("axes") else ""
        lines.append(f"  {path:<26} {str(tuple(a['shape'])):<18} {a['dtype']:<8} {_mb(a['stored_bytes'])}"
                     f" {a['compression'] or ''}{described}".rstrip())
    versions = ", ".join(f"{k} {v}" for k, v in sorted(info["versions"].items()) if not k.startswith("simulator:"))
    lines.append(f"versions:  {versions}")
    shown = {k: v for k, v in cfg.items() if k != "task"}
    lines.append("config:    " + json.dumps(shown, sort_keys=True))
    return "\n".join(lines)


def main_info(args: argparse.Namespace) -> int:
    from doabench.datasets.generate import parts_dir
    from doabench.datasets.reader import DatasetFile

    path = Path(args.path)
    folder = parts_dir(path)
    if not path.exists() and folder.is_dir():  # a make-dataset that has not finished (or was killed)
        done = sorted(int(p.stem) for p in folder.glob("*.h5") if p.stem.isdigit())
        cfg = json.loads((folder / "config.json").read_text()) if (folder / "config.json").exists() else {}
        summary = {"path": str(path), "in_progress": True, "episodes_done": len(done), "config": cfg}
        if args.json:
            print(json.dumps(summary, indent=2, sort_keys=True))
        else:
            print(f"{path} is not finished: {len(done)} episode(s) done in {folder}; rerun the same make-dataset "
                  f"command to continue\nconfig: {json.dumps({k: v for k, v in cfg.items() if k != 'task'})}")
        return 0
    with DatasetFile(path) as f:
        info = f.info()
    print(json.dumps(info, indent=2, sort_keys=True, default=str) if args.json else format_info(info))
    return 0


def main_merge(args: argparse.Namespace) -> int:
    from doabench.datasets.merge import merge_datasets

    result = merge_datasets(args.inputs, args.out)
    dup = f", {result['duplicates']} duplicate(s) kept once" if result["duplicates"] else ""
    missing = f"; {len(result['missing'])} requested episode(s) missing" if result["missing"] else ""
    print(f"wrote {result['path']}: {result['episodes']} episodes from {len(args.inputs)} file(s){dup}{missing}")
    return 0
