"""The task registry: task ids -> :class:`TaskSpec`, and their Gymnasium registration.

Built-in specs are the TOML files in the repository's ``tasks/`` folder (installed as the
``doabench.task_specs`` package). More come from folders listed in ``DOABENCH_TASK_PATH``
(``os.pathsep``-separated) and from :func:`register_task` calls, so a new task needs no edit of
doabench. Each task is registered with Gymnasium as ``doabench/<id>-v<version>``.

Dynamic task families are named by an id prefix: ``<name>:<rest>`` is resolved by the
``doabench.task_prefixes`` entry point ``name`` (``file = "doabench.datasets.replay:resolve_file_task"``
in pyproject.toml gives dataset replay, ``file:data.h5``) or by a :func:`register_prefix` call. This
module names no task kind.
"""
from __future__ import annotations

import difflib
import os
import sys
from importlib import resources
from pathlib import Path
from typing import Any, Callable

import gymnasium

from doabench.envs.spec import TaskSpec, load_spec_file, spec_from_dict
from doabench.errors import ConfigError, NotFoundError
from doabench.plugins import Registry

PREFIX_ENTRY_POINT_GROUP = "doabench.task_prefixes"

_TASKS: dict[str, TaskSpec] = {}
_LOADED = False
#: Dynamic task families by the prefix of their ids (``file`` resolves ``file:data.h5``, dataset replay),
#: doabench's own declared in its pyproject.toml as a plug-in's (:mod:`doabench.plugins`).
TASK_PREFIXES: Registry[Callable[[str], TaskSpec]] = Registry("task prefix", PREFIX_ENTRY_POINT_GROUP, declares_own=True)
# Task ids whose spec file could not be loaded at start-up -> the one-line reason. Asking for one
# of them raises that reason; every other task and command keeps working.
_BROKEN: dict[str, str] = {}


def _warn(message: str) -> None:
    print(f"doabench: warning: {message}", file=sys.stderr)


def _builtin_spec_files() -> list[Path]:
    folder = resources.files("doabench.task_specs")
    return sorted(Path(str(p)) for p in folder.iterdir() if p.name.endswith(".toml"))


def _user_spec_files() -> list[Path]:
    """The TOML files of the DOABENCH_TASK_PATH folders; an entry that is not a folder is skipped
    with a warning (it must not break ``import doabench`` and every command)."""
    files: list[Path] = []
    for entry in filter(None, os.environ.get("DOABENCH_TASK_PATH", "").split(os.pathsep)):
        folder = Path(entry)
        if not folder.is_dir():
            _warn(f"DOABENCH_TASK_PATH entry {folder} is not a folder; skipped")
            continue
        try:
            files.extend(sorted(folder.glob("*.toml")))
        except OSError as exc:
            _warn(f"DOABENCH_TASK_PATH entry {folder} cannot be read ({exc.strerror or exc}); skipped")
    return files


def _ensure_loaded() -> None:
    global _LOADED
    if _LOADED:
        return
    _LOADED = True
    for path in _builtin_spec_files() + _user_spec_files():
        _load_file_at_startup(path)


def _load_file_at_startup(path: Path) -> None:
    """Register one spec file; a broken one (bad TOML, bad spec, an id another file has) is skipped
    with a one-line warning naming it, and only its task fails, when asked for."""
    try:
        specs = load_spec_file(path)
    except (ConfigError, OSError, UnicodeDecodeError) as exc:
        reason = str(exc) if isinstance(exc, ConfigError) else f"task spec {path} cannot be read ({exc})"
        _warn(f"{reason}; skipped")
        _BROKEN.setdefault(path.stem, reason)
        return
    for spec in specs:
        old = _TASKS.get(spec.id)
        if old is not None and old.source_file != spec.source_file and old != spec:
            reason = (f"task id {spec.id!r} is defined twice, by {old.source_file} and by {spec.source_file}; "
                      "rename one")
            _warn(f"{reason}; {spec.source_file} skipped")
            _BROKEN[spec.id] = reason
            del _TASKS[spec.id]
            continue
        if spec.id in _BROKEN:
            continue
        register_task(spec)


def register_task(spec: TaskSpec | dict[str, Any] | str | Path) -> list[TaskSpec]:
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
    """Resolve ids ``<prefix>:<rest>`` (``prefix`` given as ``"file"`` or ``"file:"``) with
    ``resolver(task_id)``; another resolver under a taken prefix is a ConfigError."""
    TASK_PREFIXES.register(prefix.removesuffix(":"), resolver)


def available_tasks() -> dict[str, TaskSpec]:
    _ensure_loaded()
    return dict(sorted(_TASKS.items()))


def get_task_spec(task_id: str | TaskSpec) -> TaskSpec:
    """The spec of a registered task id (``sim-demo``, ``doabench/sim-demo-v0`` or ``file:x.h5``)."""
    if isinstance(task_id, TaskSpec):
        return task_id
    _ensure_loaded()
    head, colon, _ = task_id.partition(":")
    prefix = TASK_PREFIXES.find(head) if colon else None
    if prefix is not None:
        return prefix[1](task_id)
    key = task_id
    if key.startswith("doabench/"):
        key = key[len("doabench/"):].rsplit("-v", 1)[0]
    if key in _TASKS:
        return _TASKS[key]
    if key in _BROKEN:
        raise ConfigError(_BROKEN[key])
    close = difflib.get_close_matches(key, list(_TASKS), n=3, cutoff=0.6)
    hint = f"; did you mean {', '.join(close)}?" if close else ""
    raise NotFoundError(f"unknown task {task_id!r}{hint} (`doabench list tasks` shows them all)")
