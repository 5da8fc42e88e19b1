"""The task registry: task ids -> :class:`TaskSpec`, and their Gymnasium registration.

Built-in specs are the TOML files in the repository's ``tasks/`` folder (installed as the
``doabench.task_specs`` package). More come from folders listed in ``DOABENCH_TASK_PATH``
(``os.pathsep``-separated) and from :func:`register_task` calls, so a new task needs no edit of
doabench. Each task is registered with Gymnasium as ``doabench/<id>-v<version>``.

The ids live in one :class:`doabench.plugins.VersionedRegistry` (:data:`TASKS`): the plug-in
registries' rules (a did-you-mean for an unknown id, a broken definition named when asked for),
with Gymnasium's version discipline: ``sim-fan`` is the latest version, ``sim-fan-v1`` and
``doabench/sim-fan-v1`` exactly version 1, and a version that does not exist is a NotFoundError
naming those that do.

Dynamic task families are named by an id prefix: ``<name>:<rest>`` is resolved by the
``doabench.task_prefixes`` entry point ``name`` (``file = "doabench.datasets.replay:resolve_file_task"``
in pyproject.toml gives dataset replay, ``file:data.h5``) or by a :func:`register_prefix` call. This
module names no task kind.
"""
from __future__ import annotations

import os
import sys
from importlib import resources
from pathlib import Path
from typing import Any, Callable

import gymnasium

from doabench.envs.spec import TaskSpec, load_spec_file, spec_from_dict
from doabench.errors import ConfigError, NotFoundError
from doabench.plugins import Registry, VersionedRegistry

PREFIX_ENTRY_POINT_GROUP = "doabench.task_prefixes"

#: Every registered version of each task id (an older version stays runnable as
#: ``doabench/<id>-v<N>``, or ``<id>-v<N>``, and results files of it stay readable). A task id whose
#: spec file could not be loaded at start-up is withdrawn with the one-line reason: asking for it
#: raises that reason; every other task and command keeps working.
TASKS: VersionedRegistry[TaskSpec] = VersionedRegistry("task", lambda spec: spec.version, namespace="doabench/",
                                                       listing="`doabench list tasks` shows them all")
_LOADED = False
#: Dynamic task families by the prefix of their ids (``file`` resolves ``file:data.h5``, dataset replay),
#: doabench's own declared in its pyproject.toml as a plug-in's (:mod:`doabench.plugins`).
TASK_PREFIXES: Registry[Callable[[str], TaskSpec]] = Registry("task prefix", PREFIX_ENTRY_POINT_GROUP, declares_own=True)


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
        if TASKS.broken(path.stem) is None and not TASKS.versions(path.stem):
            TASKS.withdraw(path.stem, reason)
        return
    for spec in specs:
        old = _conflicting(spec)
        if old is not None:
            reason = (f"task id {spec.id!r} is defined twice, by {old.source_file} (v{old.version}) and by "
                      f"{spec.source_file} (v{spec.version}); rename one (the versions of a task live in one folder)")
            _warn(f"{reason}; {spec.source_file} skipped")
            TASKS.withdraw(spec.id, reason)
            continue
        if TASKS.broken(spec.id) is not None:
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
        old = _conflicting(s)
        if old is not None:
            raise ConfigError(f"task id {s.id!r} version {s.version} from {s.source_file} is already registered by "
                              f"{old.source_file}")
        TASKS.register(s.id, s, replace=True)  # _conflicting is the stricter rule: what passed it is one definition
        if s.gym_id not in gymnasium.registry:
            # the env is built from the gym id, so each registered version runs as itself
            gymnasium.register(id=s.gym_id, entry_point="doabench.envs.env:DoaEnv", kwargs={"task": s.gym_id},
                               disable_env_checker=True)
    return specs


def _conflicting(spec: TaskSpec) -> TaskSpec | None:
    """A registered spec that ``spec`` may not stand beside: another definition of its version, or
    a version of its id from another folder (every version of a task lives in one folder, so a file
    on the task path cannot add a newer version of a built-in task and replace it)."""
    versions = TASKS.versions(spec.id)
    same = versions.get(spec.version)
    if same is not None and same.source_file != spec.source_file and same != spec:
        return same
    folder = None if spec.source_file is None else Path(spec.source_file).parent
    for other in versions.values():
        if other.source_file is not None and folder is not None and Path(other.source_file).parent != folder:
            return other
    return None


def task_versions(task_id: str) -> dict[int, TaskSpec]:
    """Every registered version of ``task_id`` (``{version: spec}``, oldest first; empty when unknown)."""
    _ensure_loaded()
    return TASKS.versions(task_id)


def task_reference(spec: TaskSpec) -> str:
    """The id that resolves to exactly ``spec``: its plain id when it is the latest registered
    version, else ``<id>-v<version>``."""
    versions = TASKS.versions(spec.id)
    return spec.id if not versions or max(versions) == spec.version else f"{spec.id}-v{spec.version}"


def register_prefix(prefix: str, resolver: Callable[[str], TaskSpec]) -> None:
    """Resolve ids ``<prefix>:<rest>`` (``prefix`` given as ``"file"`` or ``"file:"``) with
    ``resolver(task_id)``; another resolver under a taken prefix is a ConfigError."""
    TASK_PREFIXES.register(prefix.removesuffix(":"), resolver)


def available_tasks() -> dict[str, TaskSpec]:
    """Each registered task id's latest version, sorted by id."""
    _ensure_loaded()
    return TASKS.latest()


def get_task_spec(task_id: str | TaskSpec) -> TaskSpec:
    """The spec of a task id (``sim-demo``, ``sim-demo-v2``, ``doabench/sim-demo-v2`` or
    ``file:x.h5``); a TaskSpec is returned as it is. Resolve an id once, where it is typed, and
    pass the spec on."""
    if isinstance(task_id, TaskSpec):
        return task_id
    return resolve_task(task_id)


def resolve_task(task_id: str) -> TaskSpec:
    """Look ``task_id`` up (:func:`get_task_spec`): the registry, or the resolver of its prefix."""
    _ensure_loaded()
    head, colon, _ = task_id.partition(":")
    prefix = TASK_PREFIXES.find(head) if colon else None
    if prefix is not None:
        return prefix[1](task_id)
    key = task_id.removeprefix(TASKS.namespace)
    head, colon, _ = key.partition(":")
    if key != task_id and colon and TASK_PREFIXES.find(head) is not None:  # a prefixed task's Gymnasium id
        return _prefixed_version(key)
    return TASKS.get(task_id)


def _prefixed_version(key: str) -> TaskSpec:
    """``file:x.h5-v0`` (from ``doabench/file:x.h5-v0``): the prefixed task, which must be of that version."""
    base, sep, number = key.rpartition("-v")
    if not sep or not number.isdigit():
        return resolve_task(key)
    spec = resolve_task(base)
    if spec.version != int(number):
        raise NotFoundError(f"task {base!r} has no version {int(number)} (it is v{spec.version}: "
                            f"`{spec.gym_id}` or `{base}`)")
    return spec
