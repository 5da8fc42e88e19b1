"""Episode sources: what turns a task spec and an episode index into an :class:`Episode`.

Each task ``kind`` has a factory ``factory(spec, **options)``; it gets the spec and the run-time
options (corpus paths, simulator backend, device) and returns an object with ``__len__``,
``episode(index) -> Episode`` and ``describe() -> dict``. A kind declares its options as a
dataclass, ``factory.Options`` (``SimulatedOptions``, ``LocataOptions``: each field a keyword, its
default and a comment saying what it does), and its scoring policy as ``factory.headline``
(``"pooled"``: the RMSAE over every frame; ``"recording_mean"``: the mean of the per-recording
RMSAEs, LOCATA's). The factory is given only the options its kind takes: one command line serves
every kind (``--locata-root`` on a simulated task is not its option), and an option no kind takes is
a one-line error naming the nearest one. Kinds come from one place, the
``doabench.task_kinds`` entry-point group (``name = "package.module:Factory"``; doabench's own
``simulated``, ``locata`` and ``dataset`` are declared in its pyproject.toml, like a plugin's), loaded
when a task of that kind is first asked for; :func:`register_task_kind` adds one at run time. This
module names no kind. Episode ``i`` of a task is a pure function of the spec and ``i``: the seed of
a simulated episode is derived from ``(base_seed, cell, i)`` with numpy's SeedSequence, never from a
running random state.
"""
from __future__ import annotations

import dataclasses
import difflib
import inspect
import sys
from typing import TYPE_CHECKING, Any, Callable, Mapping, Protocol, Sequence

import numpy as np

from doabench.envs.spec import TaskSpec
from doabench.episode import Episode
from doabench.errors import ConfigError, NotFoundError
from doabench.plugins import Registry

if TYPE_CHECKING:
    from doabench.corpora.speech import SpeechSource


class EpisodeSource(Protocol):
    def __len__(self) -> int: ...
    def episode(self, index: int) -> Episode: ...
    def describe(self) -> dict[str, Any]: ...


ENTRY_POINT_GROUP = "doabench.task_kinds"

#: Every task kind, doabench's own declared in its pyproject.toml as a plug-in's (:mod:`doabench.plugins`).
TASK_KINDS: Registry[Callable[..., EpisodeSource]] = Registry("task kind", ENTRY_POINT_GROUP, declares_own=True)


def register_task_kind(kind: str, factory: Callable[..., EpisodeSource]) -> None:
    """Register the episode-source factory ``factory(spec, **options)`` of a task kind; another
    factory under a taken kind is a ConfigError."""
    TASK_KINDS.register(kind, factory)


def available_task_kinds() -> list[str]:
    """The kinds registered or declared in the ``doabench.task_kinds`` group (none is loaded)."""
    return TASK_KINDS.names()


def task_kind(kind: str, task_id: str | None = None) -> Callable[..., EpisodeSource]:
    """The factory of task kind ``kind`` (loaded from its entry point on first use); a one-line
    error (naming ``task_id`` when given) for a kind nobody registered or declared."""
    return TASK_KINDS.get(kind, context=f"task {task_id!r}: " if task_id is not None else "")


def recorded_task_kind(kind: str) -> Callable[..., EpisodeSource] | None:
    """The factory of a task kind named by a results file: one registered already or one of
    doabench's own; None for any other (a name read from a file never loads a plug-in)."""
    found = TASK_KINDS.find_own(str(kind))
    return None if found is None else found[1]


def make_episode_source(spec: TaskSpec, **options: Any) -> EpisodeSource:
    """The episode source of ``spec``: its kind's factory, given the options (not None) its kind takes."""
    factory = task_kind(spec.kind, spec.id)
    check_options(options)
    given = {k: v for k, v in options.items() if v is not None}
    if not _takes_any_option(factory):
        taken = kind_options(factory)
        given = {k: v for k, v in given.items() if k in taken}
    return factory(spec, **given)


def say_simulation_time(source: EpisodeSource, indices: Sequence[int], workers: int = 1) -> None:
    """Print to standard error, before the work, how long simulating episodes ``indices`` of
    ``source`` takes when its engine takes more than a minute an episode (a source that can tell:
    ``source.time_note(indices, workers)``, the simulated kind's); nothing otherwise."""
    note = getattr(source, "time_note", None)
    line = note(list(indices), workers) if callable(note) and indices else None
    if line:
        print(line, file=sys.stderr, flush=True)


def task_identity(spec: TaskSpec, options: Mapping[str, Any]) -> dict[str, Any]:
    """The run-time ``options`` of a run on ``spec`` that are part of the run's identity: those
    that change its episodes or their scoring, where they differ from the task's own (its kind's
    ``Options.identity``; ``{}`` for the defaults, so a default run keeps its name). A kind whose
    ``Options`` declares no ``identity`` counts every option given that differs from its field's
    default; a kind that declares no ``Options`` counts every option given."""
    factory = task_kind(spec.kind, spec.id)
    given = {k: v for k, v in options.items() if v is not None}
    declared = getattr(factory, "Options", None)
    if not isinstance(declared, type) or not dataclasses.is_dataclass(declared):
        taken = kind_options(factory) if not _takes_any_option(factory) else set(given)
        return {k: given[k] for k in sorted(given) if k in taken}
    names = {f.name for f in dataclasses.fields(declared)}
    opts = declared(**{k: v for k, v in given.items() if k in names})
    identity = getattr(opts, "identity", None)
    if callable(identity):
        return dict(identity(spec.params))
    defaults = declared()
    return {k: getattr(opts, k) for k in sorted(names) if getattr(opts, k) != getattr(defaults, k)}


def recorded_identity(spec: TaskSpec | None, kind: str, source: Mapping[str, Any]) -> dict[str, Any]:
    """:func:`task_identity` of a run recorded before results held it, from its ``task.source``
    (the kind's ``Options.from_source``); ``{}`` where the kind or its reading is not available
    here (such a file is taken as a run of the task's defaults). The kind is looked up by
    :func:`recorded_task_kind`: reading a results file loads no plug-in."""
    declared = getattr(recorded_task_kind(kind), "Options", None)
    from_source = getattr(declared, "from_source", None)
    if not callable(from_source):
        return {}
    identity = getattr(from_source(source), "identity", None)
    return dict(identity(spec.params if spec is not None else {})) if callable(identity) else {}


def _takes_any_option(factory: Callable[..., EpisodeSource]) -> bool:
    """A plug-in factory ``f(spec, **options)`` that declares no ``Options`` is given every option."""
    if dataclasses.is_dataclass(getattr(factory, "Options", None)):
        return False
    return any(p.kind is p.VAR_KEYWORD for p in inspect.signature(factory).parameters.values())


def kind_options(factory: Callable[..., EpisodeSource]) -> set[str]:
    """The run-time options a kind takes: the fields of its ``Options`` dataclass, or (a kind that
    declares none) its factory's keyword parameters after the spec."""
    declared = getattr(factory, "Options", None)
    if declared is not None and dataclasses.is_dataclass(declared):
        return {f.name for f in dataclasses.fields(declared)}
    params = list(inspect.signature(factory).parameters.values())[1:]
    return {p.name for p in params if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}


def check_options(options: dict[str, Any]) -> None:
    """Refuse a run-time option that no task kind takes (``librispeach=...``), naming the nearest
    one: a misspelt option must not be silently ignored. Options of other kinds are accepted
    (one command line serves every kind: ``--locata-root`` on a simulated task does nothing), and
    so is ``None``, an option not given."""
    given = {k for k, v in options.items() if v is not None}
    if not given:
        return
    known = set().union(*(kind_options(f) for f in TASK_KINDS.load_all().values()))
    unknown = sorted(given - known)
    if unknown:
        name = unknown[0]
        near = difflib.get_close_matches(name, sorted(known), n=1)
        hint = f"; did you mean {near[0]!r}?" if near else f" (options: {', '.join(sorted(known))})"
        raise ConfigError(f"unknown task option {name!r}{hint}")


def episode_seed(base_seed: int, *keys: int) -> int:
    """A 63-bit seed that depends only on ``base_seed`` and ``keys`` (cell, episode index)."""
    state = np.random.SeedSequence([int(base_seed), *map(int, keys)]).generate_state(2, np.uint32)
    return int((int(state[0]) << 31) ^ int(state[1]))


def make_speech_source(speech: dict[str, Any], librispeech: str | None = None) -> SpeechSource:
    """The speech source a task's ``[speech]`` section asks for."""
    from doabench.corpora import speech as speech_mod

    corpus = speech.get("corpus", "embedded")
    if corpus == "embedded":
        return speech_mod.EmbeddedSpeechSource()
    if corpus == "librispeech":
        from doabench.corpora.paths import corpus_root

        root = corpus_root("librispeech", librispeech)
        if not root:
            raise NotFoundError(
                f"this task needs LibriSpeech {speech.get('subset', '')}: pass --librispeech PATH (Python: "
                "librispeech=PATH) or set "
                "DOABENCH_LIBRISPEECH (get it with `doabench data download librispeech --subset "
                f"{speech.get('subset', 'test-clean')}`)")
        kwargs = {k: v for k, v in speech.items() if k not in ("corpus", "subset")}
        return speech_mod.LibriSpeechSource(root, speech.get("subset", "test-clean"), **kwargs)
    raise ConfigError(f"unknown speech corpus {corpus!r} (use embedded or librispeech)")
