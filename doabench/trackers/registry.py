"""Tracker registry: ids -> classes, from the decorator, entry points or ``module:Class`` paths.

``--tracker`` text forms:

* ``srp-max`` or ``srp-max:32x64`` – a registered id, with the part after the colon passed to the
  constructor as ``spec``;
* ``package.module:Class`` or ``package.module:Class:spec`` – any importable Tracker subclass.

Third-party packages register through the ``doabench.trackers`` entry-point group
(``name = "package.module:Class"``) or by calling :func:`register_tracker` at import time.

A text is looked up once, where it is typed (:func:`tracker_ref`), and the :class:`TrackerRef`
value is passed on: :func:`make_tracker` and :func:`canonical_tracker` take either.
"""
from __future__ import annotations

import difflib
import importlib
import importlib.util
from dataclasses import dataclass
from typing import Any, Callable, Mapping, TypeVar, overload

from doabench.errors import ConfigError, DoabenchError, NotFoundError, TrackerError, one_line
from doabench.plugins import Registry
from doabench.trackers.base import Tracker

T = TypeVar("T", bound=type)

ENTRY_POINT_GROUP = "doabench.trackers"


def _check_tracker(name: str, klass: Any) -> type[Tracker]:
    if not (isinstance(klass, type) and issubclass(klass, Tracker)):
        raise ConfigError(f"register_tracker({name!r}): {klass!r} is not a doabench.Tracker subclass")
    if not klass.__dict__.get("name"):  # a class declared only by its entry point is named by it
        klass.name = name
    return klass


#: Every tracker id: doabench's own (``srp-max``, ``music``, ...) are declared in its pyproject.toml
#: in the ``doabench.trackers`` group, as the baselines and any plug-in are (:mod:`doabench.plugins`).
TRACKERS: Registry[type[Tracker]] = Registry("tracker", ENTRY_POINT_GROUP, _check_tracker, declares_own=True)


@overload
def register_tracker(name: str, cls: None = None) -> Callable[[T], T]: ...
@overload
def register_tracker(name: str, cls: type[Tracker]) -> type[Tracker]: ...
def register_tracker(name: str, cls: type[Tracker] | None = None) -> Callable[[T], T] | type[Tracker]:
    """Register a Tracker subclass under ``name``; usable as ``@register_tracker("id")``. Another
    class under a taken id is a ConfigError."""

    def decorate(klass: T) -> T:
        TRACKERS.register(name, klass)
        klass.name = name  # type: ignore[attr-defined]
        return klass

    return decorate(cls) if cls is not None else decorate


def available_trackers() -> dict[str, type[Tracker]]:
    """All trackers (built in, entry points, registered), sorted by id; a plug-in that fails to
    load is left out with a warning."""
    return TRACKERS.load_all()


def _import_class(path: str) -> type[Tracker]:
    module_name, _, attr = path.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        hint = ""
        if isinstance(exc, ModuleNotFoundError) and exc.name and module_name.split(".")[0] == exc.name.split(".")[0]:
            hint = " (is its folder on PYTHONPATH, or the package installed?)"
        raise NotFoundError(f"cannot import module {module_name}: {one_line(exc)}{hint}") from None
    except Exception as exc:  # the user's module failed while importing: name it, no traceback
        raise TrackerError(f"tracker module {module_name!r} failed to import: {one_line(exc)}") from None
    cls = getattr(module, attr, None)
    if cls is None:
        found = sorted(name for name, obj in vars(module).items()
                       if isinstance(obj, type) and issubclass(obj, Tracker) and obj is not Tracker
                       and getattr(obj, "__module__", None) == module.__name__)
        close = difflib.get_close_matches(attr, found, n=1, cutoff=0.5)
        hint = (f"; did you mean {close[0]}?" if close else "") + (
            f" (Tracker subclasses there: {', '.join(found)})" if found else " (it defines no Tracker subclass)")
        raise NotFoundError(f"module {module_name} has no class {attr!r}{hint}")
    if not (isinstance(cls, type) and issubclass(cls, Tracker)):
        raise NotFoundError(f"{path!r} is not a doabench.Tracker subclass (it is {type(cls).__name__} "
                            f"{getattr(cls, '__name__', cls)!r})")
    return cls


def _module_exists(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        return False


@dataclass(frozen=True)
class TrackerRef:
    """A ``--tracker`` text resolved: ``cls`` the class it names, ``spec`` the part after the id
    (passed to the constructor), ``name`` the tracker's id, ``base`` the id as its canonical form
    starts (``name`` for a registered class, ``module:Class`` for a class loaded by its path)."""

    text: str
    cls: type[Tracker]
    spec: str | None
    name: str
    base: str

    def with_spec(self, spec: str | None) -> "TrackerRef":
        """The same class with another spec: what resolving ``base[:spec]`` gives, without a lookup."""
        return TrackerRef(f"{self.base}:{spec}" if spec else self.base, self.cls, spec or None, self.name, self.base)


def tracker_ref(text: str | TrackerRef) -> TrackerRef:
    """Resolve a ``--tracker`` text (a TrackerRef is returned as it is); an unknown id is one line."""
    if isinstance(text, TrackerRef):
        return text
    head, sep, rest = text.partition(":")
    found = TRACKERS.find(head)  # loads this id's entry point only: other plug-ins (and torch) need not load
    if found is not None:
        return TrackerRef(text, found[1], rest or None, found[0], found[0])
    attr_text = rest.partition(":")[0]
    looks_like_class = attr_text.isidentifier() and attr_text[:1].isupper()
    if sep and ("." in head or looks_like_class or _module_exists(head)):
        attr, _, spec = rest.partition(":")
        cls = _import_class(f"{head}:{attr}")
        # a class loaded by its path keeps the path in its canonical id: the id must load it again
        base = cls.name if cls.name and TRACKERS.registered().get(cls.name) is cls else f"{head}:{attr}"
        return TrackerRef(text, cls, spec or None, cls.name or f"{head}:{attr}", base)
    raise TRACKERS.unknown(head)


def resolve_tracker(text: str | TrackerRef) -> tuple[type[Tracker], str | None, str]:
    """Parse a ``--tracker`` value into (class, spec, id) (:func:`tracker_ref` as a tuple)."""
    ref = tracker_ref(text)
    return ref.cls, ref.spec, ref.name


def parse_options(pairs: list[str] | None) -> dict[str, Any]:
    """``["key=value", ...]`` -> dict, values parsed as int/float/bool when they look like one."""
    options: dict[str, Any] = {}
    for item in pairs or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"tracker option {item!r} is not of the form key=value")
        options[key] = _parse_value(value)
    return options


def _parse_value(value: str) -> Any:
    low = value.lower()
    if low in ("true", "false"):
        return low == "true"
    for cast in (int, float):
        try:
            return cast(value)
        except ValueError:
            pass
    return value


def canonical_tracker(text: str | TrackerRef, options: Mapping[str, Any] | None = None,
                      tracker: Tracker | None = None) -> tuple[str, dict[str, Any]]:
    """The one id and options of a tracker configuration, so that aliases name one model: one
    results file name, one leaderboard row.

    * A tracker whose spec is its SRP map resolution (``resolution_in_id``) is named with the
      resolution it runs at: ``cross3d`` -> ``cross3d:16x32``, ``srp-max`` -> ``srp-max:16x32``,
      ``srp-max --tracker-opt resolution=8x16`` -> ``srp-max:8x16``.
    * Options equal to the constructor's defaults are dropped (``hold=auto``, ``seed=0``).
    * Shipped weights are named by their short name (``weights=moving``, however they were
      chosen: by name, by a path to the file or a copy of it, or as the default), except the
      tracker's plain weights (:attr:`Tracker.plain_weights_name`), which leave no option, as their
      results always had. A tracker without named weights drops ``weights=FILE`` when it says the
      file is the weights it loads by default (:attr:`Tracker.loads_default_weights`).

    ``tracker``: the instance built from ``text`` and ``options`` (built here when None); which
    weights it runs is its own answer (its weights name, its plain weights, whether it loaded its
    default), read from it alone."""
    ref, options = canonical_ref(text, options, tracker)
    return ref.text, options


def canonical_ref(text: str | TrackerRef, options: Mapping[str, Any] | None = None,
                  tracker: Tracker | None = None) -> tuple[TrackerRef, dict[str, Any]]:
    """:func:`canonical_tracker` with the canonical id as a :class:`TrackerRef` (``.text`` is the
    id): what builds the same tracker again without a lookup."""
    import inspect

    options = dict(options or {})
    ref = tracker_ref(text)
    cls, spec = ref.cls, ref.spec
    if tracker is None:
        tracker = make_tracker(ref, **options)
    resolution = tracker.resolution
    if getattr(tracker, "resolution_in_id", False) and resolution is not None:
        canonical = ref.with_spec(f"{resolution[0]}x{resolution[1]}")
        options.pop("resolution", None)
    else:
        canonical = ref.with_spec(spec)
    try:
        params: Mapping[str, inspect.Parameter] = inspect.signature(cls).parameters
    except (TypeError, ValueError):
        params = {}
    for key in list(options):
        p = params.get(key)
        if p is not None and p.default is not inspect.Parameter.empty and key != "weights" and (
                options[key] == p.default or str(options[key]) == str(p.default)):
            del options[key]
    named = tracker.weights_name
    if named is not None:
        if named == tracker.plain_weights_name:
            options.pop("weights", None)
        else:
            options["weights"] = named
        return canonical, options
    if tracker.loads_default_weights:
        options.pop("weights", None)
    return canonical, options


def make_tracker(text: str | TrackerRef, **options: Any) -> Tracker:
    """Instantiate a tracker from its ``--tracker`` text (or its :class:`TrackerRef`) and options."""
    ref = tracker_ref(text)
    cls, spec, name = ref.cls, ref.spec, ref.name
    try:
        tracker = cls(spec=spec, **options)
    except TypeError as exc:
        raise ConfigError(f"tracker {name!r}: bad options {sorted(options)}: {exc}") from None
    except DoabenchError:
        raise
    except Exception as exc:  # a plugin's constructor failed: name it, no traceback
        raise TrackerError(f"tracker {name!r} failed to start: {one_line(exc)}") from None
    if not tracker.name:
        tracker.name = name
    return tracker
