"""Results files: one JSON per run (summary, provenance, per-episode metrics, optional frames)
and a CSV of per-episode rows, both written atomically."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any, Callable, Collection, Mapping

import pandas as pd

from doabench.errors import InputError
from doabench.files import atomic_path, file_stem, write_json
from doabench.results.identity import results_delays, results_task_options, results_weights_name
from doabench.results.intervals import NO_INTERVAL_NOTE, interval_text, shown_interval
from doabench.results.labels import run_label
from doabench.results.schema import read_results


def _name_options(options: Mapping[str, Any] | None, weights_hash: str | None) -> dict[str, Any]:
    """The options as they enter a file name: a ``weights`` file stands for its content (SHA-256),
    so a retrained file at the same path gets another name and a moved file keeps its name."""
    out = {str(k): v for k, v in (options or {}).items()}
    if "weights" in out and weights_hash:
        out["weights"] = f"sha256:{weights_hash}"
    return out


def config_suffix(options: Mapping[str, Any] | None = None, delays: str = "nearest",
                  weights_hash: str | None = None, task_options: Mapping[str, Any] | None = None) -> str:
    """``""`` for a tracker's default configuration on the task's defaults (no tracker options,
    nearest delays, no task options), else ``"__" + 8 hex digits`` of the configuration, so
    different configurations never share a file. The task options enter the hashed text only when
    there are any, so every run on a task's defaults keeps the name it always had."""
    opts = _name_options(options, weights_hash)
    if not opts and delays in (None, "nearest") and not task_options:
        return ""
    named: dict[str, Any] = {"options": opts, "delays": delays or "nearest"}
    if task_options:
        named["task_options"] = dict(task_options)
    text = json.dumps(named, sort_keys=True, default=str)
    return "__" + hashlib.sha256(text.encode()).hexdigest()[:8]


def results_stem(task_id: str, tracker_id: str, options: Mapping[str, Any] | None = None, delays: str = "nearest",
                 weights_hash: str | None = None, task_options: Mapping[str, Any] | None = None,
                 weights_name: str | None = None) -> str:
    """File stem for a run, safe on every filesystem: ``sim-demo__srp-max_32x64`` for the default
    configuration, ``sim-demo__srp-kalman__1a2b3c4d`` with tracker options, exact delays or task
    options (``--backend``, ``--vad``, ...: :func:`doabench.envs.sources.task_identity`).

    A run of shipped weights is named by them (``weights_name``): ``sim-walk__cross3d_16x32__moving-long``,
    then the hash of its other options if any (``...__moving-long__1a2b3c4d``); the file itself keeps
    the weights' SHA-256. Other weights files enter the hash by their SHA-256."""
    head = f"{file_stem(task_id)}__{file_stem(tracker_id)}"
    if weights_name:
        others = {k: v for k, v in (options or {}).items() if k != "weights"}
        return f"{head}__{file_stem(weights_name)}" + config_suffix(others, delays, None, task_options)
    return head + config_suffix(options, delays, weights_hash, task_options)


def configuration(task_id: str, task_version: Any, tracker_id: str, options: Mapping[str, Any] | None,
                  weights_hash: str | None, delays: str | None,
                  task_options: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """What makes two runs the same configuration (the number of episodes does not: a run of the
    same configuration that takes the episodes of its file, or more, replaces it): the task and its
    version, the run-time options that change its episodes or scoring (``task_options``), the
    tracker, its options, weights and SRP delays."""
    return {"task": str(task_id), "task_version": None if task_version is None else int(task_version),
            "task_options": dict(task_options or {}),
            "tracker": str(tracker_id), "options": _name_options(options, weights_hash),
            "weights": weights_hash or None, "delays": delays or "nearest"}


def results_configuration(results: Mapping[str, Any]) -> dict[str, Any]:
    """:func:`configuration` of a results dictionary (or a loaded results file)."""
    task, tracker = results.get("task") or {}, results.get("tracker") or {}
    # str(): configuration() makes text of them anyway, a missing id included
    return configuration(str(task.get("id")), task.get("version"), str(tracker.get("id") or tracker.get("name")),
                         tracker.get("options"), tracker.get("weights_hash"),
                         results_delays(results), results_task_options(results))


def results_path(results: Mapping[str, Any], out_dir: str | Path) -> Path:
    """Where :func:`write_results` puts the JSON of ``results``."""
    c = results_configuration(results)
    stem = results_stem(c["task"], c["tracker"], (results["tracker"].get("options") or {}), c["delays"], c["weights"],
                        c["task_options"], results_weights_name(results))
    return Path(out_dir) / f"{stem}.json"


def _describe_difference(old: Mapping[str, Any], new: Mapping[str, Any]) -> str:
    keys = [k for k in new if old.get(k) != new.get(k)]
    return ", ".join(f"{k} {old.get(k)!r} -> {new.get(k)!r}" for k in keys) or "unknown difference"


#: the flag that replaces a results file whatever it holds (``--overwrite`` is its older name)
REPLACE = "--replace (Python: overwrite=True)"


def _episode_indices(data: Mapping[str, Any]) -> set[int]:
    """The episode indices a results dictionary holds (its rows)."""
    return {int(row["episode"]) for row in data.get("episodes") or [] if row.get("episode") is not None}


def check_overwrite(path: str | Path, config: Mapping[str, Any], overwrite: bool = False, partial: bool = False,
                    episodes: Collection[int] | Callable[[int], Collection[int]] | None = None) -> None:
    """Refuse to replace a results file whose content would be lost, unless ``overwrite``
    (``--replace``): a file of a different configuration (options, weights, task version, delays,
    task options), or one of this configuration holding an episode this run does not take.

    ``episodes``: the episode indices this run takes, or a function that gives them from the
    task's episode count (the file's ``task.episodes_total``: the same configuration has the same
    episodes). A run of the same episodes replaces its file (a rerun gives the same scores), and so
    does one that takes every episode the file holds and more (it extends the file). Without
    ``episodes``, a ``partial`` run (some episodes or cells) may not replace a complete one."""
    path = Path(path)
    if overwrite or not path.exists():
        return
    try:
        _, data = read_results(path)
        old = results_configuration(data)
        task = data.get("task") or {}
        old_complete = bool(task.get("complete", task.get("episodes_run") == task.get("episodes_total")))
        held = _episode_indices(data)
        total = int(task.get("episodes_total") or 0)
    except (OSError, InputError, ValueError, AttributeError, TypeError, KeyError):
        raise InputError(f"{path} exists and is not a readable results file; move it away or pass {REPLACE}") from None
    if dict(old) != dict(config):
        raise InputError(f"{path} holds a different configuration ({_describe_difference(old, config)}); "
                         f"pass {REPLACE} to replace it, or choose another --out")
    if callable(episodes) and not total:  # a file that does not record its task's size
        episodes = None
    if episodes is not None:
        taken = set(int(i) for i in (episodes(total) if callable(episodes) else episodes))
        dropped = held - taken
        if dropped:
            whole = "a complete run of this configuration" if old_complete else "a run of this configuration"
            raise InputError(f"{path} holds {whole} with {len(held)} episodes and this run takes "
                             f"{len(taken)}, without {len(dropped)} of them: pass {REPLACE} to replace the file, "
                             "run episodes that include them (the same --episodes and --cells, or more), or choose "
                             "another --out")
        return
    if partial and old_complete:
        raise InputError(f"{path} holds a complete run of this configuration and this run is partial (some episodes "
                         f"or cells): pass {REPLACE} to replace it, or choose another --out")


def write_results(results: dict[str, Any], out_dir: str | Path, overwrite: bool = False) -> tuple[Path, Path]:
    """Write ``<stem>.json`` and ``<stem>.csv`` into ``out_dir`` (stem: :func:`results_stem` of the
    run's configuration); returns both paths. A file under that name of a different configuration,
    or holding episodes these results do not, is refused (:func:`check_overwrite`) unless
    ``overwrite``."""
    out_dir = Path(out_dir)
    path = results_path(results, out_dir)
    task = results.get("task") or {}
    check_overwrite(path, results_configuration(results), overwrite, partial=not task.get("complete", True),
                    episodes=_episode_indices(results))
    stem = path.stem
    json_path = write_json(out_dir / f"{stem}.json", results)
    csv_path = out_dir / f"{stem}.csv"
    with atomic_path(csv_path) as tmp:
        pd.DataFrame(results["episodes"]).to_csv(tmp, index=False, float_format="%.4f")
    return json_path, csv_path


def alias_files(results: Mapping[str, Any], out_dir: str | Path) -> list[Path]:
    """Results JSON files in ``out_dir`` other than :func:`results_path` that hold the same
    configuration under another name (``sim-demo__srp-max.json``, named by an alias of its tracker
    id, now ``sim-demo__srp-max_16x32.json``): one model, one file. Only files whose name starts
    with the task and the tracker's registered name are read, an older schema as the current one."""
    target = results_path(results, out_dir)
    tracker = results.get("tracker") or {}
    prefix = f"{file_stem(results['task']['id'])}__{file_stem(tracker.get('name') or tracker.get('id'))}"
    want = results_configuration(results)
    found = []
    for path in sorted(Path(out_dir).glob(f"{prefix}*.json")):
        if path.name == target.name:
            continue
        try:
            _, old = read_results(path)
            config = results_configuration(old)
        except (OSError, InputError, ValueError, AttributeError, TypeError, KeyError):
            continue
        if config == want:
            found.append(path)
    return found


def weights_line(tracker: Mapping[str, Any]) -> str:
    """``weights: moving (sha256 8ce3ea54bcd7, cross3d-16x32-moving.safetensors)``: which weights a
    tracker (its ``describe()``, or a results file's ``tracker``) runs, as ``run`` and ``track`` print it."""
    digest = tracker.get("weights_hash")
    if not digest:
        if tracker.get("trained") is False or tracker.get("untrained"):
            return "weights: none (random initialisation, untrained)"
        return "weights: none (no learned weights)"
    name = tracker.get("weights_name") or "(not a shipped file)"
    where = tracker.get("weights") or (tracker.get("options") or {}).get("weights")
    return f"weights: {name} (sha256 {digest[:12]}" + (f", {Path(str(where)).name})" if where else ")")


#: the line ``doabench run`` prints under the tracking lag
LAG_DEFINITION = ("  lag: the delay (0-2 s) of the true direction that best fits the estimates; none where they "
                  "do not follow the talker")


def committed_results_dir() -> Path:
    """The committed results of this checkout (``results/`` beside the ``doabench`` package)."""
    return Path(__file__).resolve().parents[2] / "results"


def coverage_lines(results: Mapping[str, Any], written: str | Path | None = None,
                   committed: str | Path | None = None) -> list[str]:
    """What ``doabench run`` prints after the scores: whether the run is full or partial, and the
    figure of the committed run of the same configuration (``committed``: a results folder,
    default :func:`committed_results_dir`) when there is one, complete and other than the file
    just ``written``. A partial run is ranked apart from full runs on the leaderboards, so its
    figure is not comparable with the full-task one."""
    from doabench.results.ranking import display_path
    from doabench.results.schema import summary_problem

    task = results.get("task") or {}
    run, total = int(task.get("episodes_run") or 0), int(task.get("episodes_total") or 0)
    full = bool(task.get("complete", run == total))
    lines = [f"full run: all {total} episodes of {task.get('id')} v{task.get('version')}, ranked on its leaderboard"
             if full else
             f"partial run: {run} of {total} episodes of {task.get('id')} v{task.get('version')}, ranked apart "
             "from full runs on its leaderboard: its figures are not comparable with a full-task figure"]
    path = results_path(results, committed_results_dir() if committed is None else committed)
    if not path.is_file() or (written is not None and Path(written).resolve() == path.resolve()):
        return lines
    try:
        _, data = read_results(path)
        other = data.get("task") or {}
        same = results_configuration(data) == results_configuration(results) and bool(other.get("complete"))
        summary = data["summary"]
        figure = (f"RMSAE all frames {float(summary['rmsae_all']):.2f} "
                  f"{interval_text(shown_interval(data, 'rmsae_all'))} deg, "
                  f"voice-active {float(summary['rmsae_nonsilent']):.2f}")
        same = same and not summary_problem(data)
    except (OSError, InputError, ValueError, KeyError, TypeError, AttributeError, IndexError):
        return lines
    if same:
        lines.append(f"committed full-task run of this configuration ({display_path(path)}, "
                     f"{int(other.get('episodes_run') or 0)} episodes): {figure}")
    return lines


def format_summary(results: dict[str, Any]) -> str:
    """The table ``doabench run`` prints."""
    s = results["summary"]
    lines = [
        f"task {results['task']['id']} v{results['task']['version']} | tracker {run_label(results)} "
        f"| {results['task']['episodes_run']} episodes | causal: {str(results['causal']).lower()}",
        f"{'metric (pooled over frames)':<34}{'value':>10}",
        f"{'RMSAE all frames [deg]':<34}{s['rmsae_all']:>10.2f}   95% CI "
        f"{interval_text(shown_interval(results, 'rmsae_all'))}",
        f"{'RMSAE non-silent frames [deg]':<34}{s['rmsae_nonsilent']:>10.2f}   95% CI "
        f"{interval_text(shown_interval(results, 'rmsae_nonsilent'))}",
        f"{'MAE non-silent [deg]':<34}{s['pooled']['mae']:>10.2f}",
        f"{'median / p90 non-silent [deg]':<34}{s['pooled']['median']:>10.2f} / {s['pooled']['p90']:.2f}",
        f"{'within 5/10/20/30 deg [%]':<34}" + " / ".join(
            f"{100 * s['pooled'][f'within_{t}']:.0f}" for t in (5, 10, 20, 30)),
        f"{'azimuth MAE (LOCATA) [deg]':<34}{s['pooled']['azimuth_mae']:>10.2f}",
    ]
    rec = s.get("recording_mean")
    if rec:
        lines.insert(2, f"{'RMSAE all, mean of recordings [deg]':<34}{rec['rmsae_all']:>10.2f}   (headline, "
                        f"the paper's Table II; non-silent {rec['rmsae_nonsilent']:.2f})")
    tracker = results["tracker"]
    if tracker.get("weights_hash") or tracker.get("untrained"):  # learned trackers: which weights ran
        lines[1:1] = [weights_line({**tracker, "weights_name": results_weights_name(results)})]
    if "lag_s" in s:  # moving-talker tasks: how far behind, and the error by the talker's angular speed
        lag = s.get("lag_s")
        lines.append(f"{'tracking lag [s]':<34}{lag:>10.2f}" if lag is not None else
                     f"{'tracking lag [s]':<34}{'none':>10}   ({s.get('lag_note') or 'not defined'})")
        lines.append(LAG_DEFINITION)
    bands = {k: v for k, v in (s.get("speed_bands") or {}).items() if v.get("n_frames")}
    if bands:
        lines.append(f"{'RMSAE by angular speed [deg/s]':<34}" + "   ".join(
            f"{band}: {v['rmsae']:.2f} ({v['n_frames']} fr)" for band, v in bands.items()))
    scoring = results.get("scoring") or {}
    notes = []
    if scoring.get("vad"):
        notes.append(f"VAD {scoring['vad']}")
    if scoring.get("invalid_frames_excluded"):
        notes.append(f"{scoring['invalid_frames_excluded']} frames with invalid truth not scored")
    if scoring.get("planar_fold"):
        notes.append("planar array: scored against mirror-folded truth")
    if notes:
        lines.append("scoring: " + "; ".join(notes))
    if shown_interval(results, "rmsae_all") is None or shown_interval(results, "rmsae_nonsilent") is None:
        lines.append(f"95% CI n/a: {NO_INTERVAL_NOTE}")
    if results.get("cells"):
        lines.append(f"{'cell':<28}{'RMSAE all':>10}{'non-silent':>12}")
        for cell, c in results["cells"].items():
            lines.append(f"{cell:<28}{c['rmsae_all']:>10.2f}{c['rmsae_nonsilent']:>12.2f}")
    rtf = results.get("real_time_factor")
    lines.append(f"wall time {results['wall_time_s']:.1f} s for {results['audio_s']:.1f} s of audio"
                 + (f" ({rtf:.1f}x real time, tracker alone {results['tracker_real_time_factor']:.0f}x)" if rtf else ""))
    return "\n".join(lines)
