"""``doabench make-dataset``: generate a dataset file, resumable and safe against SIGKILL.

Crash safety (an HDF5 file killed mid-write can be unreadable, so nothing is ever appended to
the final file in place):

1. Every episode is computed (in worker processes with ``workers > 1``) and written to its own
   small HDF5 file in the journal folder ``<out>.parts/``: first as ``.NNNNNN.<pid>.tmp``, then
   closed, fsynced and renamed to ``NNNNNN.h5``. A rename is atomic, so a part either exists
   whole, with its ``complete`` attribute, or not at all.
2. When every episode of the run has its part, the parts are copied (raw compressed chunks, no
   recompression) into ``<out>.partial`` in index order, which is fsynced and renamed to
   ``<out>``; then the journal folder is removed.

A run killed at any moment leaves the journal (and maybe a stale ``.partial``, or stray ``.tmp``
files, which are deleted). Running the same command again keeps the finished parts, redoes the
rest and assembles: the result equals an uninterrupted run, because episode ``i`` is a pure
function of the task and ``i``. ``<out>.parts/config.json`` holds the generation config; a resume
with another task, features or options is refused. ``<out>.parts/lock`` (an ``flock``, released
by the kernel even on SIGKILL, with the owner's pid) stops two runs from writing the same output:
the second one gets one line naming the first.

An ``out`` that is a stream (``-``, ``/dev/stdout``, a FIFO: the output rule of
:mod:`doabench.files`) is generated in a temporary folder and written through when
complete; such a run keeps no journal, so an interrupted one starts again.
"""
from __future__ import annotations

import contextlib
import datetime as _dt
import json
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import numpy as np

from doabench.datasets.layout import EpisodeRecord, is_complete, write_episode, write_part  # noqa: F401
from doabench.datasets.schema import (
    COMPRESSIONS, EPISODES, SCHEMA, FeatureRequest, describe_dataset, dumps, episode_name, feature_names, open_h5,
    parse_features, shard_of,
)
from doabench.envs.registry import get_task_spec
from doabench.envs.selection import describe_selection, select_episodes
from doabench.envs.spec import TaskSpec
from doabench.errors import ConfigError, InputError
from doabench.files import atomic_path, exclusive_lock, resolve_output

# Config keys that may differ between shards of one dataset (see merge).
SHARD_KEYS = ("episodes", "shard")
# Config keys that say which episodes a dataset takes, not what an episode holds: episode i is the
# same whatever they are, so a journal part is reused across them. ``selection`` is "stratified"
# where --episodes N spreads over a grid's cells (absent where the first N are taken, as datasets
# made before that rule took them).
SELECTION_KEYS = SHARD_KEYS + ("selection",)
# Source options that only say where a corpus lives; they do not change the episodes.
PATH_OPTIONS = ("librispeech", "locata_root")


def parts_dir(out: str | Path) -> Path:
    out = Path(out)
    return out.with_name(out.name + ".parts")


def partial_path(out: str | Path) -> Path:
    out = Path(out)
    return out.with_name(out.name + ".partial")


def generation_config(spec: TaskSpec, requests: Sequence[FeatureRequest], episodes: int,
                      shard: tuple[int, int] | None, float16: bool, delays: str, sample_vad: bool,
                      compression: str, backend: str, device: str | None,
                      source_options: dict[str, Any] | None = None) -> dict[str, Any]:
    """The identity of a dataset: everything that changes its content (not workers or corpus paths)."""
    return json.loads(dumps({
        "task": spec.to_dict(),
        "features": [r.name for r in requests],
        "episodes": int(episodes),
        "shard": list(shard) if shard else None,
        "float16": bool(float16),
        "delays": delays,
        "sample_vad": bool(sample_vad or any(r.framed for r in requests)),
        "compression": compression,
        "backend": backend,
        "device": device or "cpu",
        "source_options": {k: v for k, v in (source_options or {}).items() if k not in PATH_OPTIONS},
    }))


def config_difference(a: dict[str, Any], b: dict[str, Any], ignore: Sequence[str] = ()) -> list[str]:
    """Top-level keys whose values differ (``task`` is reported as ``task`` or ``task.<key>``)."""
    diff = []
    for key in sorted(set(a) | set(b)):
        if key in ignore or a.get(key) == b.get(key):
            continue
        if key == "task" and isinstance(a.get(key), dict) and isinstance(b.get(key), dict):
            ta, tb = a[key], b[key]
            diff += [f"task.{k}" for k in sorted(set(ta) | set(tb)) if ta.get(k) != tb.get(k)]
        else:
            diff.append(key)
    return diff


def describe_difference(a: dict[str, Any], b: dict[str, Any], keys: list[str]) -> str:
    def get(cfg, key):
        if key.startswith("task."):
            return cfg.get("task", {}).get(key[5:])
        return cfg.get(key)

    parts = [f"{k}: {get(a, k)!r} vs {get(b, k)!r}" for k in keys[:3]]
    return "; ".join(parts) + (" ..." if len(keys) > 3 else "")


@contextlib.contextmanager
def journal_lock(folder: Path) -> Iterator[None]:
    """Exclusive lock ``folder/lock`` (released by the kernel if the process dies; the second
    process is told the first one's pid)."""
    with exclusive_lock(folder / "lock", f"{folder} (make-dataset's journal)"):
        yield


def part_tag(config: dict[str, Any]) -> str:
    """The configuration a journal part was made with, as a hash: every key that changes an
    episode's content (the shard, the episode count and their selection do not)."""
    import hashlib

    content = {k: v for k, v in config.items() if k not in SELECTION_KEYS}
    return hashlib.sha256(json.dumps(content, sort_keys=True, default=str).encode()).hexdigest()


def scan_parts(folder: Path, tag: str | None = None) -> set[int]:
    """Indices of the finished parts; stray tmp files, unreadable parts and (with ``tag``) parts made
    with another configuration than the run's (another task or features: config.json alone is not
    trusted, it may be corrupt or missing) are deleted, so those episodes are made again."""
    import h5py

    done: set[int] = set()
    for p in folder.iterdir():
        if p.name.endswith(".tmp"):
            p.unlink(missing_ok=True)
            continue
        if not (p.suffix == ".h5" and p.stem.isdigit()):
            continue
        try:
            with h5py.File(p, "r") as f:
                ok = is_complete(f[EPISODES][p.stem]) and (tag is None or f.attrs.get("part_config") == tag)
        except (OSError, KeyError):
            ok = False
        if ok:
            done.add(int(p.stem))
        else:
            p.unlink(missing_ok=True)
    return done


# -- worker processes ------------------------------------------------------------------------------
_WORKER: dict[str, Any] = {}


def _init_worker(spec: TaskSpec, requests, computer_kwargs: dict[str, Any], folder: str,
                 compression: str, tag: str = "") -> None:
    import torch

    from doabench.datasets.compute import EpisodeComputer

    # One thread per process: the processes are the parallelism, and threads would fight over cores.
    torch.set_num_threads(1)
    # Ctrl-C reaches the whole process group: the parent stops the run (and says what it kept);
    # the workers finish their episode quietly instead of each printing a traceback.
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _WORKER.update(computer=EpisodeComputer(spec, requests, **computer_kwargs), folder=Path(folder),
                   compression=compression, tag=tag)


def _work(index: int) -> int:
    record = _WORKER["computer"].compute(index)
    write_part(_WORKER["folder"], record, _WORKER["compression"], _WORKER["tag"])
    return index


# -- the command -----------------------------------------------------------------------------------
@dataclass
class GenerationResult:
    path: Path
    n_episodes: int
    computed: int
    resumed: int
    seconds: float
    already_complete: bool = False
    size: int = 0  # bytes of the file written (a stream's too)

    @property
    def episodes_per_minute(self) -> float:
        return 60.0 * self.computed / self.seconds if self.seconds > 0 else float("nan")


def make_dataset(task: str | TaskSpec, out: str | Path, episodes: int | None = None,
                 features: str | Sequence[str] = "srp:16x32", shard: tuple[int, int] | None = None,
                 workers: int | None = 1, float16: bool = False, sample_vad: bool = False, compression: str = "gzip",
                 delays: str = "nearest", device: str | None = None, backend: str = "builtin",
                 progress: bool | Callable[[int], None] = True, engine: str = "local",
                 ray_address: str | None = None, say: Callable[[str], None] | None = None,
                 **source_options: Any) -> GenerationResult:
    """Generate (or resume) dataset ``out`` with ``episodes`` episodes of ``task``, taken as
    ``doabench run`` takes them (:func:`dataset_selection`: a grid's spread over its cells, else
    the first N).

    ``shard=(k, n)`` keeps every ``n``-th of those from the ``k``-th on; ``workers`` processes simulate in
    parallel; ``source_options`` (``librispeech``, ...) go to the task's episode source.
    ``progress``: a tqdm bar (True), none (False) or a callback called with each finished index.
    ``engine="ray"``: the episodes run as Ray tasks (:mod:`.ray_engine`) on the cluster at
    ``ray_address`` or on a local Ray instance with ``workers`` CPUs; ``workers=None`` there means
    every CPU of the cluster. The file is the same whatever the engine. ``say`` is given a line
    saying which episodes the run takes before it starts (``doabench make-dataset`` prints it).
    """
    start = time.perf_counter()
    from doabench.ray_support import check_engine, require_ray

    check_engine(engine)
    if engine == "ray":
        require_ray()  # before any work: a one-line error when Ray is missing
    elif workers is None:
        workers = 1
    spec = get_task_spec(task)
    requests = parse_features(features)
    if compression not in COMPRESSIONS:
        raise ConfigError(f"unknown compression {compression!r}; choose from {', '.join(COMPRESSIONS)}")
    if workers is not None and int(workers) < 1:
        raise ConfigError(f"--workers must be at least 1, got {workers}")
    if resolve_output(out).stream:
        return _make_into_stream(out, task, dict(
            episodes=episodes, features=features, shard=shard, workers=workers, float16=float16,
            sample_vad=sample_vad, compression=compression, delays=delays, device=device, backend=backend,
            progress=progress, engine=engine, ray_address=ray_address, say=say, **source_options))
    out = Path(out)
    from doabench.envs.sources import make_episode_source, say_simulation_time

    source = make_episode_source(spec, backend=backend, device=device, **source_options)
    total = len(source)
    episodes = total if episodes is None else int(episodes)
    if not 1 <= episodes <= total:
        raise ConfigError(f"task {spec.id!r} has {total} episodes; --episodes {episodes} is out of range 1..{total}")
    config = generation_config(spec, requests, episodes, shard, float16, delays, sample_vad, compression, backend,
                               device, source_options)
    folder = parts_dir(out)
    taken, selection, note = dataset_selection(spec, total, episodes, config, out, folder)
    if selection["rule"] == "stratified":
        config["selection"] = "stratified"
    indices = shard_of(taken, shard)
    if not indices:
        assert shard is not None, "without a shard every episode is kept, and there is at least one"
        raise ConfigError(f"shard {shard[0]}/{shard[1]} of {episodes} episodes is empty")
    if say is not None:
        say(f"{spec.id}: {describe_selection(spec, total, taken, selection)}"
            + (f"; shard {shard[0]}/{shard[1]} makes {len(indices)} of them" if shard else "") + note)

    if out.exists():
        return _already_made(out, folder, config, indices, start)

    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        from doabench.files import output_error

        raise output_error(folder, exc) from None
    with journal_lock(folder):
        if out.exists():  # another process finished it while this one waited for the lock
            return _already_made(out, folder, config, indices, start)
        _check_journal_config(folder, out, config)
        tag = part_tag(config)
        done = scan_parts(folder, tag) & set(indices)
        todo = [i for i in indices if i not in done]
        say_simulation_time(source, todo, int(workers or 1))  # a slow engine says so before it starts
        computer_kwargs = {"float16": float16, "delays": delays, "sample_vad": sample_vad, "device": device,
                           "backend": backend, **source_options}
        used = _run(spec, requests, computer_kwargs, todo, folder, compression, workers, progress, source,
                    total=len(indices), initial=len(done), desc=f"{spec.id} -> {out.name}", tag=tag,
                    engine=engine, ray_address=ray_address)
        options = {k: str(v) for k, v in source_options.items()}
        generated_by = {"workers": int(used if workers is None else workers), "source_options": options,
                        "seconds": round(time.perf_counter() - start, 3)}
        if engine != "local":
            generated_by["engine"] = engine
        info = {"generated_by": generated_by, **_source_description(source)}
        assemble(out, folder, indices, config, spec, requests, info)
        shutil.rmtree(folder, ignore_errors=True)
    return GenerationResult(out, len(indices), len(todo), len(done), time.perf_counter() - start,
                            size=out.stat().st_size)


def dataset_selection(spec: TaskSpec, total: int, episodes: int, config: dict[str, Any], out: Path,
                      folder: Path) -> tuple[list[int], dict[str, Any], str]:
    """The episodes a dataset of ``episodes`` of the task's ``total`` takes, the selection's
    record and a note (empty, or why the selection is not run's): ``run``'s rule
    (:func:`~doabench.envs.selection.select_episodes`: a grid's episodes spread over its cells,
    else the first N). A dataset of a grid begun before that rule (the existing file's or the
    journal's ``config`` is this one without a ``selection`` key: it took the first N) keeps its
    first N, so that it resumes and reads as it was made."""
    taken, selection = select_episodes(spec, total, episodes)
    if selection["rule"] != "stratified":
        return taken, selection, ""
    recorded = _recorded_config(out, folder)
    if recorded is not None and "selection" not in recorded and not config_difference(recorded, config):
        return (list(range(episodes)), {"rule": "first", "episodes": episodes, "cells": None},
                f" ({out} was begun with them, before --episodes spread over a grid's cells: it keeps them; a new "
                "--out spreads them)")
    return taken, selection, ""


def _recorded_config(out: Path, folder: Path) -> dict[str, Any] | None:
    """The config an existing ``out`` or its unfinished journal records (None: neither, or a
    journal config that cannot be read, which the journal check deals with)."""
    if out.exists():
        return _existing_config(out)
    try:
        recorded = json.loads((folder / "config.json").read_text())
    except (OSError, ValueError):
        return None
    return recorded if isinstance(recorded, dict) else None


def _already_made(out: Path, folder: Path, config: dict[str, Any], indices: list[int],
                  start: float) -> GenerationResult:
    """The result of a run whose file exists: nothing to do when it has this config, else refused."""
    existing = _existing_config(out)
    diff = config_difference(existing, config)
    if diff:
        raise InputError(f"{out} exists and was made with another config "
                         f"({describe_difference(existing, config, diff)}); remove it or choose another --out")
    if folder.exists():  # killed after the final rename, before the journal was removed
        shutil.rmtree(folder, ignore_errors=True)
    return GenerationResult(out, len(indices), 0, len(indices), time.perf_counter() - start, True,
                            size=out.stat().st_size)


def _make_into_stream(out: str | Path, task: str | TaskSpec, kwargs: dict[str, Any]) -> GenerationResult:
    """``make_dataset(task, out, **kwargs)`` into a stream (``-``, a FIFO, a character device):
    made in a temporary folder, then written through."""
    import tempfile

    with tempfile.TemporaryDirectory(prefix="doabench-dataset-") as scratch:
        result = make_dataset(task, Path(scratch) / "data.h5", **kwargs)
        with atomic_path(out) as tmp:
            shutil.copyfile(result.path, tmp)
    result.path = Path(out)
    return result


def _existing_config(out: Path) -> dict[str, Any]:
    from doabench.datasets.schema import loads_attr

    with open_h5(out) as f:
        return loads_attr(f.attrs.get("config", "{}"), "config", out)


def _check_journal_config(folder: Path, out: Path, config: dict[str, Any]) -> None:
    from doabench.files import write_json

    path = folder / "config.json"
    if path.exists():
        try:
            old = json.loads(path.read_text())
        except ValueError:
            old = None
        if old is not None:
            diff = config_difference(old, config)
            if diff:
                raise ConfigError(f"{out}: an unfinished run with another config is in {folder} "
                                  f"({describe_difference(old, config, diff)}); rerun it with the same options "
                                  f"or delete {folder}")
            return
    write_json(path, config)


def _source_description(source) -> dict[str, Any]:
    try:
        d = dict(source.describe())
    except Exception:  # describe() is informative only
        d = {}
    return {"backend": d.get("simulator", ""), "simulator_versions": d.get("simulator_versions", {}), "source": d}


def _run(spec: TaskSpec, requests, computer_kwargs: dict[str, Any], todo: list[int], folder: Path,
         compression: str, workers: int | None, progress, source, total: int, initial: int, desc: str,
         tag: str = "", engine: str = "local", ray_address: str | None = None) -> int:
    """Compute the parts of ``todo``; returns the number of workers used."""
    bar = None
    if progress is True:
        from tqdm.auto import tqdm

        bar = tqdm(total=total, initial=initial, desc=desc, unit="episode", smoothing=0.1)

    def done(index: int) -> None:
        if bar is not None:
            bar.update(1)
        elif callable(progress):
            progress(index)

    try:
        if not todo:
            return int(workers or 1)
        if engine == "ray":
            from doabench.datasets.ray_engine import run_ray

            return run_ray(spec, requests, computer_kwargs, todo, folder, compression, workers, done, tag,
                           address=ray_address)
        assert workers is not None, "make_dataset gives the local engine a worker count"
        if workers == 1:
            from doabench.datasets.compute import EpisodeComputer

            computer = EpisodeComputer(spec, requests, source=source, **computer_kwargs)
            for index in todo:
                write_part(folder, computer.compute(index), compression, tag)
                done(index)
            return 1
        import multiprocessing
        from concurrent.futures import FIRST_EXCEPTION, ProcessPoolExecutor, wait

        # 'spawn': a clean interpreter per worker (fork would copy torch's thread pools and locks).
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=min(workers, len(todo)), mp_context=ctx, initializer=_init_worker,
                                 initargs=(spec, requests, computer_kwargs, str(folder), compression, tag)) as ex:
            pending = {ex.submit(_work, i) for i in todo}
            try:
                while pending:
                    finished, pending = wait(pending, return_when=FIRST_EXCEPTION)
                    for fut in finished:
                        done(fut.result())  # re-raises a worker's error here
            except BaseException:
                for fut in pending:
                    fut.cancel()
                raise
        return int(workers)
    finally:
        if bar is not None:
            bar.close()


def file_attributes(config: dict[str, Any], spec_dict: dict[str, Any], item_names: list[str], n_requested: int,
                    info: dict[str, Any]) -> dict[str, Any]:
    """Root attributes of a dataset file (see docs/hdf5-schema.md)."""
    import h5py
    import numpy
    import torch

    from doabench._version import __version__
    from doabench.provenance import git_commit

    versions = {"doabench": __version__, "torch": torch.__version__, "numpy": numpy.__version__,
                "h5py": h5py.__version__, "hdf5": h5py.version.hdf5_version}
    sim_versions = info.get("simulator_versions") or {}
    versions.update({f"simulator:{k}": str(v) for k, v in sim_versions.items()})
    return {
        "doabench_schema": SCHEMA,
        "task_id": spec_dict["id"],
        "task_version": int(spec_dict["version"]),
        "task_spec": dumps(spec_dict),
        "config": dumps(config),
        "features": dumps(item_names),
        "frames": dumps(spec_dict.get("frames", {})),
        "array": dumps(_array_dict(spec_dict)),
        "backend": str(info.get("backend") or config.get("backend", "")),
        "versions": dumps(versions),
        "git": dumps(git_commit()),
        "n_requested": int(n_requested),
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "generation": dumps({k: v for k, v in info.items()}),
    }


def _array_dict(spec_dict: dict[str, Any]) -> dict[str, Any]:
    from doabench.arrays import get_array

    try:
        return get_array(spec_dict.get("array", "nao")).to_dict()
    except Exception:  # an array file that moved: the episodes still carry their positions
        return {"name": str(spec_dict.get("array"))}


def assemble(out: Path, folder: Path, indices: Sequence[int], config: dict[str, Any], spec: TaskSpec,
             requests: Sequence[FeatureRequest], info: dict[str, Any]) -> None:
    """Copy the parts of ``indices`` into ``<out>.partial`` and rename it to ``out`` (atomic)."""
    import h5py

    # (a stale .partial from a killed assembly is removed first). The parts' raw chunks are copied:
    # their total, with room for the file's own metadata, is reserved first (HDF5 would crash the
    # process on a full disk instead of failing).
    need = sum((folder / f"{episode_name(i)}.h5").stat().st_size for i in indices) + (1 << 20)
    with atomic_path(out, tmp=partial_path(out), reserve=need) as tmp:
        with h5py.File(tmp, "w") as f:
            for k, v in file_attributes(config, spec.to_dict(), feature_names(requests), len(indices), info).items():
                f.attrs[k] = v
            # The episode indices this file is meant to hold (info reports complete / requested).
            describe_dataset(f.create_dataset("requested", data=np.asarray(indices, np.int64)), "requested")
            eps = f.create_group(EPISODES)
            for i in indices:
                name = episode_name(i)
                with h5py.File(folder / f"{name}.h5", "r") as part:
                    part.copy(part[EPISODES][name], eps, name=name)
