"""Named plug-ins: one registry type, with one set of rules, for every kind of thing doabench lets a
package add (trackers, task kinds, task-id prefixes, feature kinds, room simulators), and the task ids
themselves (:class:`VersionedRegistry`: the same rules, with Gymnasium's version discipline).

The rules, the same for each :class:`Registry`:

* **Where names come from.** An entry point of the registry's group (``name = "package.module:attr"``
  in a package's ``pyproject.toml``; doabench declares its own built-ins there, the way a plug-in
  does) or :meth:`Registry.register` at run time.
* **Lazy.** An entry point is loaded when its name is first asked for; listing names loads nothing.
* **Matching.** A name matches exactly; failing that, case-insensitively when exactly one name does
  (``Builtin`` finds ``builtin``); the object is returned under its registered name.
* **Conflicts.** Registering another object under a taken name is a ConfigError naming the holder;
  registering the same object again, or the same class re-imported (same module and qualified name),
  is not a conflict. A module that registers its own names while its entry point loads is fine.
* **Unknown names** are a NotFoundError naming the nearest names and every available one.
* **Two packages declaring one name** hold it neither: asking for it is a one-line error naming both.
* **A broken plug-in** (its entry point fails to load, or loads something the registry refuses) is a
  one-line error naming it when it is asked for by name; :meth:`Registry.load_all` (listings) warns
  and leaves it out, so one broken package does not hide the others.
"""
from __future__ import annotations

import difflib
import warnings
from importlib import metadata
from typing import Any, Callable, Generic, Iterator, Mapping, TypeVar

from doabench.errors import ConfigError, DoabenchError, NotFoundError, one_line

T = TypeVar("T")

__all__ = ["OWN_PACKAGES", "Registry", "UnknownNameError", "VersionedRegistry"]

#: The import packages of doabench's own distribution: their entry points are doabench's code.
OWN_PACKAGES = ("doabench", "doabench_baselines")


class UnknownNameError(NotFoundError, ConfigError):
    """A name no registry entry has (a NotFoundError, and a ConfigError as the setting it came from)."""


def _same(a: Any, b: Any) -> bool:
    """The same object, or the same class or function imported twice (a module reloaded)."""
    if a is b:
        return True
    key = lambda o: (getattr(o, "__module__", None), getattr(o, "__qualname__", None))  # noqa: E731
    return key(a)[1] is not None and key(a) == key(b)


class Registry(Generic[T]):
    """Names -> objects of one kind (module docstring: the rules).

    ``what``: the noun in messages (``"tracker"``); ``group``: the entry-point group (None: names
    are only registered at run time);
    ``check(name, obj) -> obj``: validates (and may adapt) what is registered, raising a
    DoabenchError for something this registry cannot hold. ``builtins``: entries defined in code
    rather than declared (the feature kinds doabench computes itself), registered from the start.
    ``declares_own``: doabench declares entries in the group itself, so a group with none means
    stale installed metadata (an unknown name then says to reinstall). ``listing``: said in an unknown
    name's message instead of every available name (a registry too long to list on one line).
    """

    def __init__(self, what: str, group: str | None, check: Callable[[str, Any], T] | None = None,
                 builtins: Mapping[str, T] | None = None, declares_own: bool = False,
                 listing: str | None = None) -> None:
        self.what, self.group, self.declares_own, self.listing = what, group, declares_own, listing
        self._check = check
        self._entries: dict[str, T] = dict(builtins or {})
        self._loading: set[str] = set()  # entry points being loaded: their module may register itself
        self._broken: dict[str, str] = {}

    # -- registering ---------------------------------------------------------------------------
    def register(self, name: str, obj: Any) -> T:
        """Register ``obj`` under ``name`` (after ``check``); returns what was registered."""
        name = str(name)
        if not name:
            raise ConfigError(f"a {self.what} needs a name")
        value = self._check(name, obj) if self._check is not None else obj
        held = self._entries.get(name)
        entry = self.declared().get(name) if held is None and name not in self._loading else None
        if entry is not None and entry.value.replace(" ", "") != _target(value):
            self._load(name)  # declared by another package (or another object): that one holds the name
            held = self._entries.get(name)
            if held is None:
                raise ConfigError(f"{self.what} {name!r} is declared by {entry.value}; choose another name for "
                                  f"{_describe(value)}")
        if held is not None and not _same(held, value):
            raise ConfigError(f"{self.what} {name!r} is already registered by {_describe(held)}; "
                              f"choose another name for {_describe(value)}")
        self._entries[name] = value
        self._broken.pop(name, None)
        return value

    def withdraw(self, name: str, reason: str) -> None:
        """Take ``name`` out (a definition that could not stand, found after it was registered):
        asking for it raises ``reason`` (a ConfigError), every other name keeps working."""
        self._entries.pop(name, None)
        self._broken[name] = reason

    def broken(self, name: str) -> str | None:
        """Why ``name`` cannot be had (withdrawn, or its plug-in failed to load), or None."""
        return self._broken.get(name)

    # -- what there is ------------------------------------------------------------------------
    def declared(self) -> dict[str, metadata.EntryPoint]:
        """The entry points of the group, by name (none is loaded)."""
        if self.group is None:
            return {}
        return {ep.name: ep for ep in metadata.entry_points(group=self.group)}

    def _claims(self, name: str) -> list[str]:
        """The different targets declared for ``name`` (more than one: two packages claim it)."""
        declared = metadata.entry_points(group=self.group) if self.group is not None else ()
        targets = {ep.value.replace(" ", ""): ep for ep in declared if ep.name == name}
        return [f"{getattr(ep.dist, 'name', None) or 'a package'}: {value}" for value, ep in targets.items()]

    def names(self) -> list[str]:
        """Every name registered or declared, sorted (none is loaded)."""
        return sorted({*self._entries, *self.declared()})

    def registered(self) -> dict[str, T]:
        """What is registered so far (nothing is loaded)."""
        return dict(self._entries)

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and self.match(name) is not None

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def match(self, name: str) -> str | None:
        """The registered or declared name ``name`` refers to (exact, else the one case-insensitive
        match), or None."""
        known = {*self._entries, *self.declared()}
        if name in known:
            return name
        folded = [k for k in known if k.lower() == str(name).lower()]
        return folded[0] if len(folded) == 1 else None

    # -- getting ------------------------------------------------------------------------------
    def find(self, name: str) -> tuple[str, T] | None:
        """``(registered name, object)`` for ``name``, loading its entry point on first use; None
        when nobody registered or declared it. A broken plug-in or a withdrawn name raises (one
        line, naming it)."""
        key = self.match(name)
        if key is None:
            if name in self._broken:
                raise ConfigError(self._broken[name])
            return None
        if key not in self._entries:
            self._load(key)
        if key not in self._entries:
            raise ConfigError(self._broken.get(key) or f"{self.what} plug-in {key!r} registered nothing")
        return key, self._entries[key]

    def find_own(self, name: str) -> tuple[str, T] | None:
        """:meth:`find` for a name read from a file someone else wrote (a results file's task kind):
        what is registered already, or what doabench itself declares (an entry point into
        :data:`OWN_PACKAGES`); None for anything else, whose entry point is not loaded. A name in a
        file never chooses a plug-in to import."""
        key = self.match(name)
        if key is None:
            return None
        if key not in self._entries:
            entry = self.declared().get(key)
            if entry is None or entry.value.split(":", 1)[0].strip().split(".", 1)[0] not in OWN_PACKAGES:
                return None
            self._load(key)
        return (key, self._entries[key]) if key in self._entries else None

    def get(self, name: str, context: str = "") -> T:
        """The object registered or declared as ``name``; an :class:`UnknownNameError` naming the
        nearest names and every available one otherwise (``context`` prefixes the message)."""
        found = self.find(name)
        if found is None:
            raise self.unknown(name, context)
        return found[1]

    def unknown(self, name: str, context: str = "") -> UnknownNameError:
        """The error for a name nobody registered or declared."""
        known = self.names()
        near = difflib.get_close_matches(str(name), known, n=3, cutoff=0.5)
        hint = f"; did you mean {', '.join(map(repr, near))}?" if near else ""
        if self.declares_own and not self.declared():
            hint += (f"; the installed doabench metadata declares no {self.group} entry points: reinstall "
                     "doabench (pip install -e .)")
        available = self.listing or f"available: {', '.join(known) or 'none'}"
        return UnknownNameError(f"{context}unknown {self.what} {name!r}{hint} ({available})")

    def load_all(self) -> dict[str, T]:
        """Every entry, each declared one loaded, sorted by name. A plug-in that fails to load is
        left out with a warning naming it."""
        for name in self.declared():
            if name not in self._entries:
                self._load(name)
                if name in self._broken:
                    warnings.warn(f"doabench: {self._broken[name]}")
        return dict(sorted(self._entries.items()))

    def _load(self, name: str) -> None:
        entry = self.declared().get(name)
        if entry is None:
            return
        if len(claims := self._claims(name)) > 1:  # neither package wins silently
            self._broken[name] = (f"{self.what} {name!r} is declared by {len(claims)} packages "
                                  f"({'; '.join(sorted(claims))}): uninstall one of them")
            return
        self._loading.add(name)  # while its module loads and registers itself, and while it is registered
        try:
            try:
                obj = entry.load()
            except Exception as exc:  # a broken plug-in is named, never a traceback
                self._broken[name] = f"{self.what} plug-in {name!r} ({entry.value}) failed to load: {one_line(exc)}"
                return
            if name in self._entries:  # its module registered it while loading: that registration stands
                if not _same(self._entries[name], obj):
                    self._broken[name] = (f"{self.what} plug-in {name!r} ({entry.value}) is not what its module "
                                          f"registered as {name!r} ({_describe(self._entries[name])})")
                return
            try:
                self.register(name, obj)
            except DoabenchError as exc:
                self._broken[name] = f"{self.what} plug-in {name!r} ({entry.value}): {exc}"
        finally:
            self._loading.discard(name)


def _target(obj: Any) -> str | None:
    """``module:qualname`` of a class or function (how an entry point names it); None otherwise."""
    module, qualname = getattr(obj, "__module__", None), getattr(obj, "__qualname__", None)
    return f"{module}:{qualname}" if isinstance(module, str) and isinstance(qualname, str) else None


def _describe(obj: Any) -> str:
    module, qualname = getattr(obj, "__module__", None), getattr(obj, "__qualname__", None)
    if module and qualname:
        return f"{module}.{qualname}"
    return repr(obj)


class VersionedRegistry(Generic[T]):
    """Ids with versions, Gymnasium's way: ``id`` is the latest version, ``id-vN`` exactly version
    N, and a version that does not exist is a NotFoundError naming those that do.

    The ids are a :class:`Registry` (its rules: exact or the one case-insensitive match, a
    did-you-mean for an unknown id, a withdrawn id raising its reason) whose entries are each id's
    ``{version: object}`` map. ``version(obj)`` reads an object's version; ``namespace`` is a
    prefix an id may be typed with (``"doabench/"``: Gymnasium's ids). An id that is itself
    registered wins over reading its ``-vN`` ending as a version.
    """

    def __init__(self, what: str, version: Callable[[T], int], namespace: str = "", listing: str | None = None) -> None:
        self.ids: Registry[dict[int, T]] = Registry(what, None, listing=listing)
        self._version, self.namespace = version, namespace

    def register(self, name: str, obj: T, replace: bool = False) -> T:
        """Add ``obj`` as version ``version(obj)`` of ``name``; another object under a taken version
        is a ConfigError naming the holder (the same object again is not), unless ``replace`` (the
        caller's own rule found the two to be one definition, edited)."""
        found = self.ids.find(name) if self.ids.broken(name) is None else None
        versions = found[1] if found is not None and found[0] == name else self.ids.register(name, {})
        number = self._version(obj)
        held = versions.get(number)
        if held is not None and not replace and not _same(held, obj) and held != obj:
            raise ConfigError(f"{self.ids.what} {name!r} version {number} is already registered by {_describe(held)}")
        versions[number] = obj
        return obj

    def withdraw(self, name: str, reason: str) -> None:
        """Take every version of ``name`` out: asking for it raises ``reason`` (a ConfigError)."""
        self.ids.withdraw(name, reason)

    def broken(self, name: str) -> str | None:
        return self.ids.broken(name)

    def versions(self, name: str) -> dict[int, T]:
        """Every version of ``name``, oldest first (empty when unknown)."""
        found = self.ids.find(name) if self.ids.broken(name) is None else None
        return dict(sorted(found[1].items())) if found is not None else {}

    def latest(self) -> dict[str, T]:
        """Each id's latest version, sorted by id."""
        return {name: versions[max(versions)] for name, versions in sorted(self.ids.registered().items()) if versions}

    def get(self, text: str) -> T:
        """The object ``text`` names: ``id`` or ``<namespace>id`` (the latest version), ``id-vN``
        or ``<namespace>id-vN`` (exactly N)."""
        key = text.removeprefix(self.namespace)
        found = self.ids.find(key)
        if found is not None and found[1]:
            return found[1][max(found[1])]
        base, sep, number = key.rpartition("-v")
        if sep and number.isdigit() and (found := self.ids.find(base)) is not None and found[1]:
            versions = found[1]
            if int(number) not in versions:
                have = ", ".join(f"v{v}" for v in sorted(versions))
                raise NotFoundError(f"{self.ids.what} {found[0]!r} has no version {int(number)} (registered: {have}; "
                                    f"`{self.namespace}{found[0]}-v{max(versions)}` or `{found[0]}` is the latest)")
            return versions[int(number)]
        raise self.ids.unknown(key)
