"""Read a dataset file: its attributes, its complete episodes, one episode's arrays.

Only groups whose ``complete`` attribute is True count as episodes; anything else is ignored
(a dataset made by ``make-dataset`` never holds one, but a hand-made or foreign file might).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable

import numpy as np

from doabench.arrays import MicArray
from doabench.datasets.layout import is_complete, read_metadata
from doabench.datasets.schema import EPISODES, TRUTH_KEYS, episode_name, loads_attr, open_h5, parse_feature
from doabench.errors import InputError, NotFoundError
from doabench.features.kinds import FEATURE_KINDS, item_name, storage_path
from doabench.framing import FrameSpec


def _text(value: Any) -> str | None:
    """An HDF5 string attribute as text (h5py may give bytes), None when absent."""
    return value.decode() if isinstance(value, bytes) else None if value is None else str(value)


def check_truth(truth: dict[str, np.ndarray], where: str) -> None:
    """Refuse truth that would score as NaN: non-numeric, non-finite, zero or misshapen directions,
    non-finite times, a VAD of another length."""
    try:
        d = np.asarray(truth["directions"], np.float64)
        times = np.asarray(truth["times"], np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{where}: truth is not numeric") from None
    if d.ndim != 2 or d.shape[1] != 3:
        raise InputError(f"{where}: truth/directions has shape {d.shape}; expected (frames, 3)")
    n = len(d)
    for key in ("elevation", "azimuth", "times", "vad"):
        if key in truth and np.shape(truth[key]) != (n,):
            raise InputError(f"{where}: {key} has shape {np.shape(truth[key])}; expected ({n},) like the directions")
    bad = ~np.all(np.isfinite(d), axis=1) | ~np.any(d, axis=1)
    if bad.any():
        raise InputError(f"{where}: truth/directions holds {int(bad.sum())} non-finite or zero vector(s) "
                         f"(first at frame {int(np.argmax(bad))}); the file is corrupt")
    if not np.all(np.isfinite(times)):
        raise InputError(f"{where}: truth/times holds non-finite values; the file is corrupt")
    for key in ("elevation", "azimuth"):
        if key in truth and not np.all(np.isfinite(np.asarray(truth[key], np.float64))):
            raise InputError(f"{where}: truth/{key} holds non-finite values; the file is corrupt")


class DatasetFile:
    """A read-only dataset file. ``DatasetFile(path)``; use as a context manager or call close().

    Attributes: ``path``, ``task_id``, ``task_version``, ``config`` (generation config dict),
    ``task_spec`` (the task's spec dict), ``items`` (stored feature names, e.g. ``srp:16x32``,
    ``srp_max:16x32``, ``gcc``, ``audio``), ``frames`` (:class:`FrameSpec`), ``indices`` (sorted
    task episode indices of the complete episodes).
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.file = open_h5(self.path)
        try:
            a = self.file.attrs
            self.task_id = str(a.get("task_id", ""))
            self.task_version = int(a.get("task_version", 0))
            self.config: dict[str, Any] = loads_attr(a.get("config", "{}"), "config", self.path)
            self.task_spec: dict[str, Any] = loads_attr(a.get("task_spec", "{}"), "task_spec", self.path)
            self.items: list[str] = list(loads_attr(a.get("features", "[]"), "features", self.path))
            self.frames = FrameSpec(**loads_attr(a.get("frames", "{}"), "frames", self.path))
            requested = [int(i) for i in self.file["requested"][()]] if "requested" in self.file else None
            eps = self.file[EPISODES]
            self.n_groups = len(eps)
            self.indices = sorted(int(name) for name, g in eps.items() if name.isdigit() and is_complete(g))
            self.requested: list[int] = list(self.indices) if requested is None else requested
        except (OSError, KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, InputError):
                self.file.close()
                raise
            self.file.close()
            raise InputError(f"{self.path}: unreadable dataset ({type(exc).__name__}: {exc})") from None

    # -- basics ------------------------------------------------------------------------------------
    def __enter__(self) -> "DatasetFile":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self.file.close()

    def __len__(self) -> int:
        return len(self.indices)

    @property
    def array(self) -> MicArray:
        d = loads_attr(self.file.attrs.get("array", "{}"), "array", self.path)
        if "positions" not in d:
            from doabench.arrays import get_array

            return get_array(d.get("name", "nao"))
        return MicArray(d.get("name", "array"), np.asarray(d["positions"]), bool(d.get("planar", False)),
                        source=str(self.path))

    def attr_json(self, name: str, default: Any = None) -> Any:
        return loads_attr(self.file.attrs[name], name, self.path) if name in self.file.attrs else default

    # -- names -------------------------------------------------------------------------------------
    def resolve(self, name: str) -> str:
        """A stored item name for ``name`` (``srp`` alone means the only stored srp resolution)."""
        if name in self.items:
            return name
        kind, sep, res = str(name).partition(":")
        found = FEATURE_KINDS.find(kind)
        if found is not None and found[1].on_grid:
            if not sep:
                cands = [i for i in self.items if i.split(":")[0] == kind]
                if len(cands) == 1:
                    return cands[0]
            else:
                canonical = item_name(kind, parse_feature(f'{kind}:{res}').resolution)
                if canonical in self.items:
                    return canonical
        raise NotFoundError(f"{self.path} does not store feature {name!r} (it has {', '.join(self.items) or 'none'})")

    @staticmethod
    def item_path(item: str) -> str:
        """Path of a stored item inside an episode group."""
        return storage_path(item)

    # -- episodes ----------------------------------------------------------------------------------
    def group(self, index: int):
        name = episode_name(index)
        eps = self.file[EPISODES]
        if name not in eps or not is_complete(eps[name]):
            raise NotFoundError(f"{self.path} has no complete episode {index}")
        return eps[name]

    def read(self, index: int, items: Iterable[str]) -> dict[str, np.ndarray]:
        """Stored features of episode ``index``: ``{name: (T, ...)}`` (audio: ``(M, L)``)."""
        g = self.group(index)
        out = {}
        for name in items:
            path = self.item_path(self.resolve(name))
            if path not in g:
                raise InputError(f"{self.path}: episode {index} lacks {path} (corrupt file?)")
            out[name] = self._load(g, path, index)
        return out

    def _load(self, g, path: str, index: int) -> np.ndarray:
        try:
            return g[path][()]
        except (OSError, KeyError) as exc:
            raise InputError(f"{self.path}: episode {index}: cannot read {path} (corrupt file: {exc})") from None

    def truth(self, index: int) -> dict[str, np.ndarray]:
        """Per-frame truth: directions (T, 3), elevation, azimuth, times (T,), vad (T,) bool."""
        g = self.group(index)
        out = {k: self._load(g, f"truth/{k}", index) for k in TRUTH_KEYS}
        out["vad"] = np.asarray(self._load(g, "vad", index), bool)
        check_truth(out, f"{self.path}: episode {index}")
        return out

    def metadata(self, index: int) -> dict[str, Any]:
        return read_metadata(self.group(index))

    def has(self, index: int, path: str) -> bool:
        return path in self.group(index)

    # -- summary -----------------------------------------------------------------------------------
    def info(self) -> dict[str, Any]:
        """What ``doabench dataset info`` prints: task, episodes, features and shapes, sizes, config."""
        size = self.path.stat().st_size
        shapes: dict[str, Any] = {}
        if self.indices:
            g = self.group(self.indices[0])

            def visit(path, obj):
                if hasattr(obj, "dtype") and path != "metadata":
                    stored = obj.id.get_storage_size()
                    shapes[path] = {"shape": list(obj.shape), "dtype": str(obj.dtype), "stored_bytes": int(stored),
                                    "compression": obj.compression,
                                    # None in files written before the datasets described themselves
                                    "units": _text(obj.attrs.get("units")), "axes": _text(obj.attrs.get("axes"))}

            g.visititems(visit)
        return {
            "path": str(self.path),
            "schema": self.file.attrs.get("doabench_schema"),
            "task": self.task_id,
            "task_version": self.task_version,
            "episodes_complete": len(self.indices),
            "episodes_requested": len(self.requested),
            "episodes_missing": sorted(set(self.requested) - set(self.indices)),
            "incomplete_groups": self.n_groups - len(self.indices),
            "index_range": [self.indices[0], self.indices[-1]] if self.indices else None,
            "features": self.items,
            "arrays": shapes,
            "file_bytes": size,
            "bytes_per_episode": size / len(self.indices) if self.indices else None,
            "frames": self.frames.to_dict(),
            "backend": self.file.attrs.get("backend"),
            "versions": self.attr_json("versions", {}),
            "created": self.file.attrs.get("created"),
            "config": self.config,
        }
