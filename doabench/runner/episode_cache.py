"""An on-disk cache of simulated episodes, so that several trackers run on one task simulate each
episode once (a sweep of four trackers over a pyroomacoustics task spends most of its time in the
simulator otherwise: about 20 s per 20 s episode at T60 0.9 s).

Opt-in: set ``DOABENCH_EPISODE_CACHE=DIR``. An episode is stored as ``DIR/<task>-<key>-<seed>.npz``
(float32 audio and float64 truth, about 23 MB for 20 s of 12 channels) where ``key`` hashes the
task's spec (without its episode counts: a cell's episode ``j`` has the same seed however many the
cell has), its episode source's description (simulator backend and versions, speech corpus, scene
overrides) and doabench's version, so a changed simulator or task never reuses a stale file. Files are written
atomically; a damaged one is rendered again. Only simulated tasks are cached (recordings are read
from disk anyway). The cached episode equals the rendered one bit for bit.
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any, Protocol, TypeGuard

import numpy as np

from doabench.arrays import MicArray
from doabench.envs.env import DoaEnv
from doabench.envs.sources import EpisodeSource
from doabench.envs.spec import TaskSpec
from doabench.episode import Episode
from doabench.files import atomic_path

ENV_VAR = "DOABENCH_EPISODE_CACHE"
_OPTIONAL = ("sample_valid", "input_vad")


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

    def path(self, index: int) -> Path:
        return self.folder / f"{self.prefix}-{int(self.source.episode_seed(index))}.npz"

    def episode(self, index: int) -> Episode:
        path = self.path(index)
        if path.is_file():
            try:
                return _load(path)
            except (OSError, ValueError, KeyError):  # damaged (e.g. a disk that filled up): render again
                pass
        episode = self.source.episode(index)
        _store(path, episode)
        return episode


def _store(path: Path, ep: Episode) -> None:
    arrays = {"audio": ep.audio, "fs": np.int64(ep.fs), "sample_vad": ep.sample_vad,
              "sample_directions": ep.sample_directions, "metadata": np.array(json.dumps(ep.metadata, default=str))}
    for name in _OPTIONAL:
        if getattr(ep, name) is not None:
            arrays[name] = getattr(ep, name)
    if ep.array is not None:
        arrays["array_positions"] = ep.array.positions
        arrays["array_name"] = np.array(ep.array.name)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)


def _load(path: Path) -> Episode:
    with np.load(path, allow_pickle=False) as z:
        array = MicArray(str(z["array_name"]), z["array_positions"], source=str(path)) if "array_positions" in z else None
        return Episode(audio=z["audio"], fs=int(z["fs"]), sample_vad=z["sample_vad"],
                       sample_directions=z["sample_directions"], metadata=json.loads(str(z["metadata"])), array=array,
                       **{name: z[name] for name in _OPTIONAL if name in z})


def cache_episodes(env: DoaEnv) -> None:
    """Wrap ``env``'s episode source in a :class:`CachedEpisodes` when ``DOABENCH_EPISODE_CACHE``
    names a folder and the task is simulated (its source describes a simulator)."""
    folder = os.environ.get(ENV_VAR)
    if not folder or isinstance(env.source, CachedEpisodes):
        return
    source = env.source
    if "simulator" not in source.describe() or not _is_seeded(source):
        return
    env.source = CachedEpisodes(source, folder, env.spec_task)
