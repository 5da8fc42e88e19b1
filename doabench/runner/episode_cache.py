"""An on-disk cache of simulated episodes, so that several trackers run on one task simulate each
episode once (a sweep of four trackers over a pyroomacoustics task spends most of its time in the
simulator otherwise: about 20 s per 20 s episode at T60 0.9 s).

Opt-in: set ``DOABENCH_EPISODE_CACHE=DIR``. An episode is stored as ``DIR/<task>-<key>-<seed>.npz``
(float32 audio and float64 truth, about 23 MB for 20 s of 12 channels) where ``key`` hashes the
task's spec (without its episode counts: a cell's episode ``j`` has the same seed however many the
cell has), its episode source's description (simulator backend and versions, speech corpus, scene
overrides) and doabench's version, so a changed simulator or task never reuses a stale file. Files are written
atomically. Each file carries a SHA-256 checksum of its content (every array's name, type, shape
and bytes) and of the name it is stored under, checked whenever it is read: a file that fails it
(a flipped byte, a disk that filled up, audio edited in an otherwise valid file, another
episode's file copied over it, a file from before checksums) is never used: the episode is
rendered again and stored afresh, with a one-line warning naming the file. Only simulated tasks
are cached (recordings are read from disk anyway). The cached episode equals the rendered one bit
for bit. A cache path that is not a folder (a file) is one line before any episode is rendered.
"""
from __future__ import annotations

import hashlib
import json
import os
import warnings
import zipfile
from pathlib import Path
from typing import Any, Protocol, Sequence, TypeGuard

import numpy as np

from doabench.arrays import MicArray
from doabench.envs.env import DoaEnv
from doabench.envs.sources import EpisodeSource
from doabench.envs.spec import TaskSpec
from doabench.episode import Episode
from doabench.errors import ConfigError
from doabench.files import atomic_path

ENV_VAR = "DOABENCH_EPISODE_CACHE"
_OPTIONAL = ("sample_valid", "input_vad")
#: The member of a cached file holding the checksum of the others.
CHECKSUM = "checksum"


class SeededSource(EpisodeSource, Protocol):
    """An episode source whose episodes are a pure function of their seed (a simulator's)."""

    def episode_seed(self, index: int) -> int: ...


def _is_seeded(source: EpisodeSource) -> TypeGuard[SeededSource]:
    return hasattr(source, "episode_seed")


class CachedEpisodes:
    """Wraps an episode source: ``episode(i)`` loads ``i`` from ``folder`` or renders and stores it."""

    def __init__(self, source: SeededSource, folder: str | Path, spec: TaskSpec) -> None:
        from doabench._version import __version__

        self.source, self.folder = source, Path(folder)
        described = spec.to_dict()
        described.pop("episodes", None)
        params = dict(described.get("params", {}))
        params.pop("cells", None)  # the cells' ids follow from the grid
        if "grid" in params:
            params["grid"] = {k: v for k, v in dict(params["grid"]).items() if k != "episodes_per_cell"}
        described["params"] = params
        text = json.dumps({"spec": described, "source": source.describe(), "doabench": __version__},
                          sort_keys=True, default=str)
        self.prefix = f"{spec.id}-{hashlib.sha256(text.encode()).hexdigest()[:16]}"

    def __len__(self) -> int:
        return len(self.source)

    def __getattr__(self, name: str) -> Any:  # describe(), stored_features, ... of the wrapped source
        return getattr(self.source, name)

    def time_note(self, indices: Sequence[int], workers: int = 1) -> str | None:
        """The wrapped source's time note for the episodes of ``indices`` not cached yet."""
        note = getattr(self.source, "time_note", None)
        todo = [i for i in indices if not self.path(i).is_file()]
        return note(todo, workers) if callable(note) and todo else None

    def path(self, index: int) -> Path:
        return self.folder / f"{self.prefix}-{int(self.source.episode_seed(index))}.npz"

    def episode(self, index: int) -> Episode:
        path = self.path(index)
        if path.is_file():
            try:
                return _load(path)
            except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
                # damaged or changed: never used; rendered again and stored afresh
                reason = (str(exc).strip().splitlines() or [type(exc).__name__])[0] if zipfile.is_zipfile(path) \
                    else "not an .npz file"
                warnings.warn(f"episode cache: {path} is not usable ({reason}); the episode is rendered again",
                              stacklevel=2)
        episode = self.source.episode(index)
        _store(path, episode)
        return episode


def checksum(arrays: dict[str, np.ndarray], name: str) -> str:
    """SHA-256 of a cached file's ``arrays`` (each one's name, type, shape and bytes, in name order)
    and of the file ``name`` they are stored under."""
    digest = hashlib.sha256(name.encode())
    for key in sorted(arrays):
        a = np.ascontiguousarray(arrays[key])
        digest.update(f"\0{key}\0{a.dtype.str}\0{a.shape}\0".encode())
        digest.update(a.tobytes())
    return digest.hexdigest()


def _store(path: Path, ep: Episode) -> None:
    arrays = {"audio": ep.audio, "fs": np.int64(ep.fs), "sample_vad": ep.sample_vad,
              "sample_directions": ep.sample_directions, "metadata": np.array(json.dumps(ep.metadata, default=str))}
    for name in _OPTIONAL:
        if getattr(ep, name) is not None:
            arrays[name] = getattr(ep, name)
    if ep.array is not None:
        arrays["array_positions"] = ep.array.positions
        arrays["array_name"] = np.array(ep.array.name)
    arrays = {k: np.asarray(v) for k, v in arrays.items()}
    arrays[CHECKSUM] = np.array(checksum(arrays, path.name))
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)


def _load(path: Path) -> Episode:
    """The episode stored at ``path``; a ValueError when its checksum fails or is missing."""
    with np.load(path, allow_pickle=False) as z:
        arrays = {name: z[name] for name in z.files}
    stored = str(arrays.pop(CHECKSUM, ""))
    if stored != checksum(arrays, path.name):
        raise ValueError("its checksum does not match its content" if stored else "it has no checksum")
    a = arrays
    array = MicArray(str(a["array_name"]), a["array_positions"], source=str(path)) if "array_positions" in a else None
    return Episode(audio=a["audio"], fs=int(a["fs"]), sample_vad=a["sample_vad"],
                   sample_directions=a["sample_directions"], metadata=json.loads(str(a["metadata"])), array=array,
                   **{name: a[name] for name in _OPTIONAL if name in a})


def cache_folder(folder: str) -> Path:
    """The cache folder ``folder`` (from ``DOABENCH_EPISODE_CACHE``), created if missing; a path
    that is not a folder, or one that cannot be created, is a one-line ConfigError."""
    path = Path(folder).expanduser()
    if path.exists() and not path.is_dir():
        raise ConfigError(f"the episode cache {ENV_VAR}={folder} is not a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"cannot create the episode cache folder {ENV_VAR}={folder}: "
                          f"{exc.strerror or type(exc).__name__}") from None
    return path


def cache_episodes(env: DoaEnv) -> None:
    """Wrap ``env``'s episode source in a :class:`CachedEpisodes` when ``DOABENCH_EPISODE_CACHE``
    names a folder and the task is simulated (its source describes a simulator)."""
    folder = os.environ.get(ENV_VAR)
    if not folder or isinstance(env.source, CachedEpisodes):
        return
    source = env.source
    if "simulator" not in source.describe() or not _is_seeded(source):
        return
    env.source = CachedEpisodes(source, cache_folder(folder), env.spec_task)
