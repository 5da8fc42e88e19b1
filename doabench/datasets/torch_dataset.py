"""A map-style ``torch.utils.data.Dataset`` over the episodes of a dataset file.

Item format (stable; documented in docs/hdf5-schema.md)::

    {
        "features":   {name: float tensor (T, ...)},   # e.g. "srp:8x16" -> (T, 8, 16); "audio" -> (M, L)
        "directions": float32 tensor (T, 3),           # unit vectors, array frame
        "vad":        bool tensor (T,),
        "times":      float32 tensor (T,),             # seconds, window centres
        "index":      int,                             # the task's episode index
    }

All episodes of a task have the same duration, so the default ``DataLoader`` collate stacks
items into ``(B, T, ...)`` batches. The HDF5 file is opened lazily in each process that reads
(h5py handles must not cross a fork), so ``num_workers > 0`` works.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import torch

from doabench.datasets.reader import DatasetFile
from doabench.errors import ConfigError, NotFoundError


class EpisodeDataset(torch.utils.data.Dataset):
    """``EpisodeDataset(path, features=("srp:8x16",), episodes=None, dtype=torch.float32, transform=None)``.

    ``features``: stored feature names (``srp:8x16``, ``srp_max:8x16``, ``gcc``, ``spectrogram``,
    ``audio``; plain ``srp`` when the file stores one resolution); ``episodes``: task episode
    indices to serve (default: every complete episode, sorted); ``dtype``: feature dtype (float16
    maps are converted); ``transform``: called on each item before it is returned.
    """

    def __init__(self, path: str | Path, features: Sequence[str] = ("srp",), episodes: Sequence[int] | None = None,
                 dtype: torch.dtype = torch.float32, transform: Callable[[dict], Any] | None = None) -> None:
        self.path = Path(path)
        if isinstance(features, str):
            features = (features,)
        with DatasetFile(self.path) as f:
            self.names = tuple(features)
            self._stored = tuple(f.resolve(n) for n in self.names)  # validates the names now
            available = set(f.indices)
            self.task_id, self.frames, self.config = f.task_id, f.frames, f.config
        if episodes is None:
            self.indices = sorted(available)
        else:
            self.indices = [int(i) for i in episodes]
            missing = sorted(set(self.indices) - available)
            if missing:
                raise NotFoundError(f"{self.path} has no complete episode(s) {missing[:5]}")
        if not self.names:
            raise ConfigError("EpisodeDataset needs at least one feature name")
        self.dtype = dtype
        self.transform = transform
        self._file: DatasetFile | None = None
        self._pid: int | None = None

    def __len__(self) -> int:
        return len(self.indices)

    def _reader(self) -> DatasetFile:
        if self._file is None or self._pid != os.getpid():
            self._file = DatasetFile(self.path)
            self._pid = os.getpid()
        return self._file

    def __getitem__(self, i: int) -> Any:
        if not -len(self) <= i < len(self):
            raise IndexError(f"item {i} out of range for {len(self)} episodes")
        index = self.indices[i]
        f = self._reader()
        stored = f.read(index, self._stored)
        truth = f.truth(index)
        item = {
            "features": {name: torch.from_numpy(np.ascontiguousarray(stored[s])).to(self.dtype)
                         for name, s in zip(self.names, self._stored)},
            "directions": torch.from_numpy(truth["directions"].astype(np.float32)),
            "vad": torch.from_numpy(truth["vad"]),
            "times": torch.from_numpy(truth["times"].astype(np.float32)),
            "index": index,
        }
        return self.transform(item) if self.transform else item

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_file"] = None  # reopened in the receiving process
        return state
