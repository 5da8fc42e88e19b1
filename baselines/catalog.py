"""Which weights is this: the one module that answers it. Every shipped weights file of a tracker
has a short name, as torchvision's weight enums do, and each tracker has a default chosen by a
stated rule (docs/models.md). Here are the names, the files, their SHA-256, the catalog and the
default; the learned trackers ask these functions and derive none of it themselves.
:mod:`.weights` reads and writes the files and checks them against ``SHA256SUMS``; it never
imports this module.

The catalog is ``baselines/weights/catalog.json``::

    {"format": "doabench-weights-catalog/1",
     "weights": [{"tracker": "cross3d:16x32", "name": "moving", "file": "cross3d-16x32-moving.safetensors",
                  "run": "cross3d-16x32-moving", "task": "sim-train-moving",
                  "headline": {"sim-grid": {"rmsae_all": 12.05, "lag_s": 0.35, ...}, ...}}, ...],
     "defaults": {"cross3d": "cross3d:16x32", "cross3d:16x32": "moving", ...}}

``tracker`` is the canonical id the file's weights run as; ``name`` is what ``--tracker-opt
weights=NAME`` types. ``defaults`` holds, per canonical id, the name used without a weights option,
and per tracker whose id names a map resolution (``cross3d``) the canonical id that the bare name
runs as. ``headline`` (where a task's ``lag_s`` is null, its ``lag_note`` says why: the run's own
note, or that the run predates the lag measurement) and ``defaults`` are written by
``scripts/weights_catalog.py`` from the committed results (:func:`write_catalog`), by the rule of
``doabench.results.default_weights``; names, files and runs are written by hand when a file ships.
A file's SHA-256 is the one the manifest (``SHA256SUMS``) records (:func:`shipped_sha256`), which
loading checks.

The *plain* weights of a tracker are the file named ``<model>[-<res>].safetensors`` (the paper
recipe's, :func:`plain_file`): a run with them carries no weights option, as results always had, so
their results keep their names; every other named file is a ``weights=NAME`` option of the run.
Where the catalog names no default, a tracker runs its plain weights, and the bare id of a model
with map resolutions the finest resolution that has plain weights (:func:`plain_resolution`).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import doabench
from doabench.errors import ConfigError, InputError
from doabench.trackers import parse_resolution, resolution_text

from . import weights as W

FORMAT = "doabench-weights-catalog/1"
CATALOG_NAME = "catalog.json"
#: ``weights=default``: the tracker's default, as without the option
DEFAULT = "default"


@dataclass(frozen=True)
class NamedWeights:
    """One shipped weights file: its tracker's canonical id, short name and file, the training run
    it came from and its task, and headline figures from the committed results."""

    tracker: str
    name: str
    file: str
    run: str | None = None
    task: str | None = None
    headline: Mapping[str, Any] = field(default_factory=dict)

    @property
    def path(self) -> Path:
        return Path(W.SHIPPED_DIR) / self.file

    @property
    def sha256(self) -> str | None:
        """The SHA-256 the manifest records for the file (loading checks the file against it)."""
        return shipped_sha256(self.file)


def shipped_sha256(file: str) -> str | None:
    """The SHA-256 that the manifest (``SHA256SUMS``) records for a shipped file name, None where it
    lists none: the hash by which a loaded file is known as a shipped one."""
    return W.read_manifest(W.SHIPPED_DIR).get(file)


#: what an entry of ``weights`` holds: required keys, then optional ones, with their types
ENTRY_KEYS: dict[str, tuple[type, ...]] = {"tracker": (str,), "name": (str,), "file": (str,)}
OPTIONAL_KEYS: dict[str, tuple[type, ...]] = {"run": (str, type(None)), "task": (str, type(None)), "headline": (dict,)}


def read_catalog(folder: str | Path | None = None) -> dict[str, Any]:
    """The catalog as stored (``{"weights": [], "defaults": {}}`` where a folder has none), checked
    by :func:`check_catalog`: a damaged or edited catalog is a one-line InputError."""
    folder = Path(folder or W.SHIPPED_DIR)
    path = folder / CATALOG_NAME
    if not path.is_file():
        return {"format": FORMAT, "weights": [], "defaults": {}}
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as exc:
        raise InputError(f"{path} is not valid JSON ({type(exc).__name__}: {exc}); reinstall doabench") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise InputError(f"{path} is not a {FORMAT} catalog; reinstall doabench")
    check_catalog(data, path, folder)
    return data


def catalog_path() -> Path:
    """Where the catalog of the shipped weights is (``baselines/weights/catalog.json``)."""
    return Path(W.SHIPPED_DIR) / CATALOG_NAME


def write_catalog(data: Mapping[str, Any]) -> Path:
    """Write the catalog (:func:`check_catalog`'s form first), two-space indented JSON with the keys
    in their given order, atomically."""
    path = catalog_path()
    check_catalog(data, path, path.parent)
    with doabench.atomic_path(path) as tmp:
        tmp.write_text(json.dumps(dict(data), indent=2, sort_keys=False) + "\n")
    return path


def check_catalog(data: Mapping[str, Any], path: Path, folder: Path) -> None:
    """The catalog's schema: ``weights`` a list of entries with the keys and types of
    :data:`ENTRY_KEYS` and :data:`OPTIONAL_KEYS`, one entry per tracker and name and per file, each
    ``file`` a plain file name in the weights folder (no folder part, no ``..``, not absolute,
    ``.safetensors``) that is not a symbolic link or anything but a regular file; ``defaults`` a
    mapping of texts. An InputError naming the entry otherwise."""
    entries, defaults = data.get("weights", []), data.get("defaults", {})
    if not isinstance(entries, list) or not isinstance(defaults, dict):
        raise InputError(f"{path}: \"weights\" must be a list and \"defaults\" a mapping; reinstall doabench")
    bad_default = next((k for k, v in defaults.items() if not isinstance(v, str)), None)
    if bad_default is not None:
        raise InputError(f"{path}: the default of {bad_default!r} is not a text; reinstall doabench")
    names: dict[tuple[str, str], int] = {}
    files: dict[str, int] = {}
    for number, entry in enumerate(entries, start=1):
        where = f"{path}: weights entry {number}"
        if not isinstance(entry, dict):
            raise InputError(f"{where} is not a mapping; reinstall doabench")
        missing = [k for k in ENTRY_KEYS if k not in entry]
        if missing:
            raise InputError(f"{where} lacks {', '.join(map(repr, missing))}; reinstall doabench")
        for key, types in {**ENTRY_KEYS, **OPTIONAL_KEYS}.items():
            if key in entry and not isinstance(entry[key], types):
                raise InputError(f"{where}: {key!r} is {type(entry[key]).__name__}, not "
                                 f"{' or '.join('null' if t is type(None) else t.__name__ for t in types)}; "
                                 "reinstall doabench")
        tracker, name, file = entry["tracker"], entry["name"], entry["file"]
        where = f"{path}: weights {tracker} {name!r} (entry {number})"
        if (tracker, name) in names:
            raise InputError(f"{where}: entry {names[tracker, name]} has that tracker and name too; a name "
                             "names one file; reinstall doabench")
        if file in files:
            raise InputError(f"{where}: file {file!r} is listed by entry {files[file]} too; reinstall doabench")
        names[tracker, name], files[file] = number, number
        confined_file(folder, file, where)


def confined_file(folder: Path, file: str, where: str) -> Path:
    """``folder / file`` for a catalog's ``file``: refused in one line unless ``file`` is a plain
    ``.safetensors`` file name (no folder part, not ``..``, not absolute) whose path is not a
    symbolic link, and is a regular file where it exists."""
    plain = bool(file) and "/" not in file and "\\" not in file and file not in (".", "..") and Path(file).name == file
    if not plain or not file.endswith(".safetensors"):
        raise InputError(f"{where}: file {file!r} is not a .safetensors file name in {folder}; shipped weights "
                         "lie in the weights folder itself; reinstall doabench")
    target = folder / file
    if target.is_symlink():
        raise InputError(f"{where}: {target} is a symbolic link; shipped weights are regular files in {folder}; "
                         "reinstall doabench")
    if target.exists() and not target.is_file():
        raise InputError(f"{where}: {target} is not a regular file; reinstall doabench")
    return target


def tracker_id(model_name: str, resolution: tuple[int, int] | None) -> str:
    """``cross3d:16x32``, or ``gcc-cnn1d`` for a model without a map resolution."""
    return model_name if resolution is None else f"{model_name}:{resolution_text(resolution)}"


def split_tracker_id(tracker: str) -> tuple[str, tuple[int, int] | None]:
    """A catalog's tracker id as its model name and map resolution: ``cross3d:16x32`` ->
    ``("cross3d", (16, 32))``, ``gcc-cnn1d`` -> ``("gcc-cnn1d", None)``."""
    model, _, resolution = tracker.partition(":")
    return model, parse_resolution(resolution) if resolution else None


def plain_file(model_name: str, resolution: tuple[int, int] | None) -> str:
    """The file name of a tracker's plain weights: ``cross3d-16x32.safetensors``, ``gcc-cnn1d.safetensors``."""
    suffix = f"-{resolution_text(resolution)}" if resolution is not None else ""
    return f"{model_name}{suffix}.safetensors"


def shipped_resolutions(model_name: str) -> list[tuple[int, int]]:
    """The map resolutions at which ``model_name`` has plain shipped weights, smallest first."""
    found = []
    for path in Path(W.SHIPPED_DIR).glob(f"{model_name}-*.safetensors"):
        try:  # cross3d-16x32 is plain; cross3d-16x32-moving is not
            found.append(parse_resolution(path.stem[len(model_name) + 1:]))
        except ConfigError:
            continue
    return sorted(found, key=lambda r: (r[0] * r[1], r))


def plain_resolution(model_name: str) -> tuple[int, int] | None:
    """The resolution the bare id of ``model_name`` runs at where the catalog names none: the finest
    with plain shipped weights (None where it has none)."""
    shipped = shipped_resolutions(model_name)
    return shipped[-1] if shipped else None


def all_named() -> list[NamedWeights]:
    """Every named weights file of the catalog; where there is no catalog, each shipped file named
    like a plain one (``<model>[-<res>].safetensors``) is that model's ``paper`` weights."""
    entries = read_catalog()["weights"]
    if entries:
        return [NamedWeights(**{k: e[k] for k in ("tracker", "name", "file", "run", "task", "headline") if k in e})
                for e in entries]
    found = []
    for path in sorted(Path(W.SHIPPED_DIR).glob("*.safetensors")):
        if path.is_symlink() or not path.is_file():  # shipped weights are regular files of the folder
            continue
        head, _, tail = path.stem.rpartition("-")
        try:  # cross3d-16x32, max-cnn1d-64x128: the last part is a resolution
            resolution = parse_resolution(tail) if head else None
        except ConfigError:
            resolution = None
        model = head if resolution is not None else path.stem
        found.append(NamedWeights(tracker_id(model, resolution), "paper", path.name))
    return found


def named_weights(model_name: str, resolution: tuple[int, int] | None) -> dict[str, NamedWeights]:
    """``{name: entry}`` of one tracker's shipped weights, by name."""
    wanted = tracker_id(model_name, resolution)
    return {e.name: e for e in all_named() if e.tracker == wanted}


def plain_name(model_name: str, resolution: tuple[int, int] | None) -> str | None:
    """The name of the plain weights (``<model>[-<res>].safetensors``), None where none ships."""
    plain = plain_file(model_name, resolution)
    return next((n for n, e in named_weights(model_name, resolution).items() if e.file == plain), None)


def default_name(model_name: str, resolution: tuple[int, int] | None) -> str | None:
    """The name a tracker runs without a weights option: the catalog's default, else its plain
    weights; None where it ships none."""
    names = named_weights(model_name, resolution)
    chosen = read_catalog()["defaults"].get(tracker_id(model_name, resolution))
    if chosen in names:
        return str(chosen)
    return plain_name(model_name, resolution)


def default_resolution(model_name: str) -> tuple[int, int] | None:
    """The map resolution the bare tracker name runs at (``cross3d`` -> 16x32): the catalog's
    default for the model, else :func:`plain_resolution`."""
    chosen = read_catalog()["defaults"].get(model_name)
    if isinstance(chosen, str) and ":" in chosen:
        return split_tracker_id(chosen)[1]
    return plain_resolution(model_name)


def default_entry(model_name: str, resolution: tuple[int, int] | None) -> NamedWeights | None:
    """The catalog entry of the weights a tracker runs without a weights option (None: it ships none)."""
    name = default_name(model_name, resolution)
    return None if name is None else named_weights(model_name, resolution)[name]


def is_default(model_name: str, resolution: tuple[int, int] | None, sha256: str | None) -> bool:
    """Whether a file of this SHA-256 is the one the tracker runs without a weights option, wherever
    it was read from (the shipped file, a copy of it)."""
    entry = default_entry(model_name, resolution)
    return bool(sha256) and entry is not None and entry.sha256 == sha256


def name_of(model_name: str, resolution: tuple[int, int] | None, sha256: str | None) -> str | None:
    """The name of the shipped weights with this SHA-256 for this tracker (None: not shipped)."""
    if not sha256:
        return None
    return next((n for n, e in named_weights(model_name, resolution).items() if e.sha256 == sha256), None)


def resolve(model_name: str, resolution: tuple[int, int] | None, weights: str | None) -> Path | None:
    """The shipped file that ``weights`` names for this tracker: None (or ``default``) is its
    default; a name of :func:`named_weights` is that file. Returns None when ``weights`` is not a
    name (a file path, which the caller reads). A name-like value (no folder, no ``.safetensors``)
    that names nothing here is refused in one line, with the names this tracker has and the
    trackers whose name it is."""
    names = named_weights(model_name, resolution)
    if weights is None or str(weights) == DEFAULT:
        name = default_name(model_name, resolution)
        return names[name].path if name is not None else None
    text = str(weights)
    if text in names:
        return names[text].path
    if "/" in text or "\\" in text or text.endswith(".safetensors") or Path(text).expanduser().exists():
        return None
    here = tracker_id(model_name, resolution)
    known = ", ".join([DEFAULT, *sorted(names)]) if names else "none (no weights ship for it)"
    elsewhere = sorted(e.tracker for e in all_named() if e.name == text)
    hint = f"; {text!r} names weights of {', '.join(elsewhere)}" if elsewhere else ""
    raise ConfigError(f"unknown weights {text!r} for {here}: its weights names are {known}{hint} "
                      "(or give a weights file path)")


def find_weights(model_name: str, resolution: tuple[int, int] | None, weights: str | None) -> W.WeightsFile | None:
    """The weights file that ``weights`` names for ``model_name`` at ``resolution``, its metadata
    read: None (or ``default``) is the default (None when it has none), a name is that shipped file,
    anything else a file path (:func:`resolve` refuses an unknown name in one line). The file must
    hold a ``model_name`` model."""
    path = resolve(model_name, resolution, weights)
    if path is None and weights is not None:
        path = Path(str(weights)).expanduser()
    return None if path is None else W.WeightsFile.read(path, model_name)


def listing(model_name: str) -> list[dict[str, Any]]:
    """Every catalog entry of ``model_name`` (all its resolutions) as ``doabench list weights`` and
    ``describe`` show it (``doabench.Tracker.shipped_weights``): ``tracker``, ``name``, ``default``,
    ``file``, ``sha256``, ``task``, ``run``, ``headline``; sorted by tracker id, its default first."""
    out = []
    for entry in all_named():
        model, resolution = split_tracker_id(entry.tracker)
        if model != model_name:
            continue
        out.append({"tracker": entry.tracker, "name": entry.name, "default": default_name(model, resolution) == entry.name,
                    "file": entry.file, "sha256": entry.sha256, "task": entry.task, "run": entry.run,
                    "headline": dict(entry.headline)})
    return sorted(out, key=lambda d: (d["tracker"], not d["default"], d["name"]))
