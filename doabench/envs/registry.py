"""The task registry: task ids -> :class:`TaskSpec`, and their Gymnasium registration.

Built-in specs are the TOML files in the repository's ``tasks/`` folder (installed as the
``doabench.task_specs`` package). More come from folders listed in ``DOABENCH_TASK_PATH``
(``os.pathsep``-separated) and from :func:`register_task` calls, so a new task needs no edit of
doabench. Each task is registered with Gymnasium as ``doabench/<id>-v<version>``.
"""
from __future__ import annotations

import difflib
import os
from importlib import resources
from pathlib import Path
from typing import Callable

import gymnasium

from doabench.envs.spec import TaskSpec, load_spec_file, spec_from_dict
from doabench.errors import ConfigError, NotFoundError

_TASKS: dict[str, TaskSpec] = {}
_LOADED = False
# Dynamic task families resolved from their id prefix, e.g. "file:data.h5" (dataset replay).
_PREFIX_RESOLVERS: dict[str, Callable[[str], TaskSpec]] = {}


def _builtin_spec_files() -> list[Path]:
    folder = resources.files("doabench.task_specs")
    return sorted(Path(str(p)) for p in folder.iterdir() if p.name.endswith(".toml"))


def _user_spec_files() -> list[Path]:
    files: list[Path] = []
    for entry in filter(None, os.environ.get("DOABENCH_TASK_PATH", "").split(os.pathsep)):
        folder = Path(entry)
        if not folder.is_dir():
            raise ConfigError(f"DOABENCH_TASK_PATH entry {folder} is not a folder")
        files.extend(sorted(folder.glob("*.toml")))
    return files


def _ensure_loaded() -> None:
    global _LOADED
    if _LOADED:
        return
    _LOADED = True
    for path in _builtin_spec_files() + _user_spec_files():
        for spec in load_spec_file(path):
            register_task(spec)


def register_task(spec: TaskSpec | dict | str | Path) -> list[TaskSpec]:
    """Register a task (a TaskSpec, a spec mapping, or a TOML file) and its Gymnasium id.

    Returns the specs registered (a grid file registers its cells and itself).
    """
    if isinstance(spec, TaskSpec):
        specs = [spec]
    elif isinstance(spec, dict):
        specs = spec_from_dict(spec)
    else:
        specs = load_spec_file(spec)
    for s in specs:
        old = _TASKS.get(s.id)
        if old is not None and old.source_file != s.source_file and old != s:
            raise ConfigError(f"task id {s.id!r} from {s.source_file} is already registered by {old.source_file}")
        _TASKS[s.id] = s
        if s.gym_id not in gymnasium.registry:
            gymnasium.register(id=s.gym_id, entry_point="doabench.envs.env:DoaEnv", kwargs={"task": s.id},
                               disable_env_checker=True)
    return specs


def register_prefix(prefix: str, resolver: Callable[[str], TaskSpec]) -> None:
    """Resolve ids starting with ``prefix`` (e.g. ``"file:"``) with ``resolver(task_id)``."""
    _PREFIX_RESOLVERS[prefix] = resolver


def available_tasks() -> dict[str, TaskSpec]:
    _ensure_loaded()
    return dict(sorted(_TASKS.items()))


def get_task_spec(task_id: str | TaskSpec) -> TaskSpec:
    """The spec of a registered task id (``sim-demo``, ``doabench/sim-demo-v0`` or ``file:x.h5``)."""
    if isinstance(task_id, TaskSpec):
        return task_id
    _ensure_loaded()
    if task_id.startswith("file:") and "file:" not in _PREFIX_RESOLVERS:
        import doabench.datasets  # noqa: F401  (registers the "file:" resolver of dataset replay)
    for prefix, resolver in _PREFIX_RESOLVERS.items():
        if task_id.startswith(prefix):
            return resolver(task_id)
    key = task_id
    if key.startswith("doabench/"):
        key = key[len("doabench/"):].rsplit("-v", 1)[0]
    if key in _TASKS:
        return _TASKS[key]
    close = difflib.get_close_matches(key, list(_TASKS), n=3, cutoff=0.6)
    hint = f"; did you mean {', '.join(close)}?" if close else ""
    raise NotFoundError(f"unknown task {task_id!r}{hint} (`doabench list tasks` shows them all)")
