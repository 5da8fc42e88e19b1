"""``doabench describe --tracker X`` / ``--task Y``: a readable summary; ``--json``: the whole record.

A tracker's summary names its weights (the shipped name, or the file), the task they were trained
on, the epochs (the exported one and the run's), the training precision, the validation RMSAE,
the headline figures the weights catalog holds for shipped weights, and the SHA-256. A task's
summary gives its version, kind, episodes and grid, speech, array and frames. ``--json`` prints
the record the summary is read from (``Tracker.describe()``, the task spec), for scripts."""
from __future__ import annotations

import argparse
import csv
from pathlib import Path
from typing import Any, Mapping, Sequence

from doabench.cli.common import add_tracker_options

#: the validation figures a training record holds, as a summary words them (the trainer's names)
VALIDATION_LABELS = {"val_rmsae_all": "all frames", "val_rmsae_nonsilent": "voice-active",
                     "val_rmsae_held": "all frames held in silences"}
#: the width of a summary's field names
FIELD_WIDTH = 14


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("describe", help="summarise a tracker and its weights, or a task (--json: the whole record)",
                       description="Summarise a tracker (with --tracker-opt weights=NAME, weights=FILE or "
                                   "weights=random: those weights) or a task in a few readable lines; --json "
                                   "prints the whole record (the weights' training record, the task's spec) as JSON.")
    add_tracker_options(p, required=False)
    p.add_argument("--task", help="describe a task instead")
    p.add_argument("--json", action="store_true", help="print the whole record as JSON instead of the summary")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from doabench.errors import ConfigError
    from doabench.files import to_json

    if bool(args.tracker) == bool(args.task):
        raise ConfigError("give exactly one of --tracker or --task")
    if args.task:
        from doabench.envs.registry import get_task_spec

        spec = get_task_spec(args.task)
        record = {**spec.to_dict(), "gym_id": spec.gym_id, "source_file": spec.source_file}
        print(to_json(record) if args.json else "\n".join(task_summary(record, f"--task {args.task}")))
        return 0
    from doabench.trackers.registry import make_tracker, parse_options

    tracker = make_tracker(args.tracker, **parse_options(args.tracker_opt))
    record = tracker.describe()
    if args.json:
        print(to_json(record))
        return 0
    typed = " ".join([f"--tracker {args.tracker}", *(f"--tracker-opt {o}" for o in args.tracker_opt)])
    print("\n".join(tracker_summary(record, type(tracker).shipped_weights(), type(tracker).__doc__, typed)))
    return 0


def _field(name: str, value: str) -> str:
    return f"  {name:<{FIELD_WIDTH}} {value}"


def run_as(record: Mapping[str, Any]) -> str:
    """The id a tracker runs as: its name with the map resolution where the id carries it
    (``cross3d`` -> ``cross3d:16x32``), else with its spec."""
    if record.get("resolution_in_id") and record.get("resolution"):
        return f"{record['name']}:{record['resolution']}"
    return f"{record['name']}:{record['spec']}" if record.get("spec") else str(record["name"])


def tracker_summary(record: Mapping[str, Any], shipped: Sequence[Mapping[str, Any]], doc: str | None,
                    typed: str) -> list[str]:
    """The lines ``describe --tracker`` prints: ``record`` is the tracker's ``describe()``, ``shipped``
    its class's ``shipped_weights()`` (the catalog: name, default, training run, headline figures),
    ``doc`` its class docstring and ``typed`` the options that select it (for the ``--json`` hint)."""
    from doabench.cli.listing import summary
    from doabench.cli.weights_text import weights_label

    digest = record.get("weights_hash")
    entry = next((w for w in shipped if digest and w.get("sha256") == digest), None)
    label = weights_label(record)
    head = run_as(record) + (f", {label}" if label else ", no learned weights")
    if entry is not None and entry.get("default"):
        head += f" (the default of {entry['tracker']})"
    lines = [head]
    described = summary(doc)
    if described:
        lines.append(_field("what", described))
    lines.append(_field("model", _model_text(record)))
    lines.append(_field("input", _input_text(record)))
    if digest:
        lines.append(_field("weights file", str(record.get("weights") or "?")))
        lines.append(_field("sha256", str(digest)))
        lines += _training_lines(record.get("training") or {}, shipped, entry)
        lines += _figure_lines(entry)
    elif record.get("trained") is False:
        lines.append(_field("weights", "none: random initialisation (run, track and export refuse it unless weights=random)"))
    lines.append(f"The whole record: doabench describe {typed} --json")
    return lines


def _model_text(record: Mapping[str, Any]) -> str:
    parts = [f"{record.get('model') or record['name']} v{record.get('version')}"]
    if record.get("parameters"):
        parts.append(f"{int(record['parameters']):,} parameters")
    parts.append("causal" if record.get("causal") else "offline (the whole episode at once)")
    frames = record.get("receptive_field_frames")
    seconds = record.get("receptive_field_s")
    if frames is None:
        parts.append("every past frame counts (no bounded receptive field)")
    else:
        parts.append(f"receptive field {frames} frame{'s' if frames != 1 else ''}" + (f" ({seconds:g} s)" if seconds else ""))
    if record.get("hold_frames"):
        parts.append(f"holds its estimate after {record['hold_frames']} silent frames")
    return "; ".join(parts)


def _input_text(record: Mapping[str, Any]) -> str:
    frame = record.get("frame") or {}
    text = ", ".join(record.get("features") or []) or "?"
    if record.get("resolution"):
        text += f" at {record['resolution']}"
    if frame:
        text += f"; frames of {frame.get('window')} samples, hop {frame.get('hop')}, at {frame.get('fs')} Hz"
    if record.get("array"):
        text += f"; array {record['array']}"
    return text


def _training_lines(training: Mapping[str, Any], shipped: Sequence[Mapping[str, Any]],
                    entry: Mapping[str, Any] | None) -> list[str]:
    """Task, epochs, precision, compute and validation of a weights file's training record."""
    if not training:
        return [_field("trained on", "not recorded in the weights file")]
    recipe = training.get("recipe") or {}
    task = str(training.get("task") or "?") + (f" v{training['task_version']}" if training.get("task_version") else "")
    if recipe:
        task += (f" (recipe {recipe.get('name', '?')}: {recipe.get('epochs', '?')} epochs x "
                 f"{recipe.get('trajectories_per_epoch', '?')} trajectories of {recipe.get('duration_s', 20):g} s)")
    start = training.get("fine_tuned_from") or {}
    if start:
        before = next((w["name"] for w in shipped if start.get("sha256") and w.get("sha256") == start["sha256"]), None)
        task += f"; fine-tuned from {before or start.get('weights') or 'other weights'} (sha256 {str(start.get('sha256'))[:12]})"
    lines = [_field("trained on", task)]
    epochs = _epochs_text(training, recipe, entry)
    if epochs:
        lines.append(_field("epochs", epochs))
    if training.get("precision"):
        stored = training.get("stored_dtype")
        lines.append(_field("precision", str(training["precision"]) + (f" (stored as {stored})" if stored else "")))
    if training.get("compute_s") is not None:
        text = f"{float(training['compute_s']) / 3600:.1f} h"
        if training.get("trajectories_seen"):
            text += f" and {int(training['trajectories_seen']):,} trajectories"
        text += " to the exported epoch"
        if training.get("compute_s_total") is not None:
            text += f" ({float(training['compute_s_total']) / 3600:.1f} h with the weights it started from)"
        if training.get("hardware"):
            text += f"; {training['hardware']}"
        lines.append(_field("compute", text))
    validation = training.get("validation") or {}
    figures = [f"{float(validation[k]):.2f} deg {label}" for k, label in VALIDATION_LABELS.items() if k in validation]
    if figures:
        lines.append(_field("validation", "RMSAE " + ", ".join(figures)
                            + (f" ({training['validation_set']})" if training.get("validation_set") else "")))
    return lines


def _epochs_text(training: Mapping[str, Any], recipe: Mapping[str, Any], entry: Mapping[str, Any] | None) -> str:
    """``epoch 24 of the 65 the run trained (the recipe planned 80), exported as the best by ...``:
    the exported epoch (the weights' record), how many the run went (its committed log, where this
    checkout has it) and the recipe's."""
    exported = training.get("epochs_completed")
    if exported is None:
        return ""
    run_epochs = _run_epochs(entry.get("run") if entry else None)
    text = f"epoch {exported}" + (f" of the {run_epochs} the run trained" if run_epochs else "")
    if recipe.get("epochs") and recipe["epochs"] != run_epochs:
        text += f" (the recipe planned {recipe['epochs']})"
    if training.get("checkpoint") == "best":
        by = training.get("best_epoch_by")
        text += ", exported as the best" + (f" by validation RMSAE {VALIDATION_LABELS.get(by, by)}" if by else "")
    else:
        text += ", exported as the run's last"
    return text


def training_runs_dir() -> Path:
    """The committed training runs of this checkout (``training-runs/`` beside the ``doabench`` package)."""
    return Path(__file__).resolve().parents[2] / "training-runs"


def _run_epochs(run: str | None) -> int | None:
    """The last epoch in a shipped run's committed ``log.csv`` (None outside a checkout that has it)."""
    if not run or "/" in run or run in (".", ".."):
        return None
    from doabench.errors import InputError
    from doabench.reporting.plots import read_training_log

    try:
        epochs = read_training_log(training_runs_dir() / run / "log.csv")["epoch"]
    except (OSError, InputError, csv.Error):
        return None
    epochs = epochs[epochs == epochs]  # NaN cells are not epochs
    return int(epochs.max()) if epochs.size else None


def _figure_lines(entry: Mapping[str, Any] | None) -> list[str]:
    """The headline figures the weights catalog holds for shipped weights, one task a line."""
    from doabench.cli.weights_text import lag_legend, lag_text

    if entry is None:
        return [_field("figures", "none recorded: not a shipped weights file (doabench run scores it on a task)")]
    headline = entry.get("headline") or {}
    if not headline:
        return [_field("figures", "none: no complete run of these weights in the committed results")]
    lines = [_field("figures", "pooled RMSAE [deg], all frames / voice-active, and the tracking lag, of the complete "
                               "runs in the committed results:")]
    width = max(len(t) for t in headline)
    for task, f in headline.items():
        lines.append(f"    {task:<{width}}  {float(f['rmsae_all']):6.2f} / {float(f['rmsae_nonsilent']):6.2f}  "
                     f"{lag_text(f):<23} {int(f.get('episodes') or 0)} episodes")
    legend = lag_legend(headline.values())
    if legend:
        lines.append(f"    ({legend})")
    if entry.get("run"):
        lines.append(_field("training run", f"training-runs/{entry['run']} (card.md: why and how it was trained)"))
    return lines


def task_summary(record: Mapping[str, Any], typed: str) -> list[str]:
    """The lines ``describe --task`` prints from the task's record (its spec's ``to_dict()``)."""
    params = record.get("params") or {}
    lines = [f"{record['id']} v{record['version']} ({record['kind']}; Gymnasium id {record.get('gym_id')})",
             _field("what", str(record.get("description") or ""))]
    episodes = f"{record.get('episodes')}"
    grid = params.get("grid") or {}
    if grid.get("t60") and grid.get("snr"):
        t60 = ", ".join(f"{v:g}" for v in grid["t60"])
        snr = ", ".join(f"{v:g}" for v in grid["snr"])
        cells = len(grid["t60"]) * len(grid["snr"])
        episodes += f": {cells} cells (T60 {t60} s x SNR {snr} dB) of {grid.get('episodes_per_cell')}"
    if "scene" in params:  # a simulated task draws its scenes from this seed on
        episodes += f"; scenes drawn from seed {record.get('base_seed')}"
    lines.append(_field("episodes", episodes))
    speech = params.get("speech") or {}
    if speech:
        lines.append(_field("speech", " ".join(str(speech[k]) for k in ("corpus", "subset") if speech.get(k))))
    locata = params.get("locata") or {}
    if locata:
        lines.append(_field("LOCATA", ", ".join(f"{k} {v}" for k, v in locata.items())))
    lines.append(_field("array", str(record.get("array"))))
    frame = record.get("frames") or {}
    if frame:
        lines.append(_field("frames", f"{frame.get('window')} samples, hop {frame.get('hop')}, at {frame.get('fs')} Hz"))
    if record.get("source_file"):
        lines.append(_field("spec file", str(record["source_file"])))
    lines.append(f"The whole record (scene parameters too): doabench describe {typed} --json")
    return lines
