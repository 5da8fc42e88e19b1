"""Replay a dataset file as a task: ``--task file:data.h5`` (task kind ``dataset``).

``get_task_spec("file:data.h5")`` builds a spec of kind ``dataset`` from the file (the original
task's version, array, frames); episode ``j`` of the replay task is the file's ``j``-th stored
episode in index order (its original index is in the metadata as ``episode_index``).

:class:`DatasetEpisodes` serves episodes two ways:

* ``stored_features(index, observations)``: the hook :meth:`DoaEnv.load_episode` calls first,
  with the environment's :class:`~doabench.features.spec.ObservationSpec`. When the file stores
  its kinds on its grid, frames and delay mode, it returns ``(episode, features, truth)`` read from the
  file (no simulation, no feature computation); otherwise None.
* ``episode(index)``: an :class:`Episode` with the stored audio, so the environment computes any
  feature itself (needs a file that stores the recording: the ``audio`` feature).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from doabench.arrays import MicArray
from doabench.datasets.reader import DatasetFile
from doabench.datasets.schema import stores_recording
from doabench.envs.options import DatasetOptions
from doabench.envs.spec import TaskSpec
from doabench.episode import Episode
from doabench.errors import InputError, NotFoundError
from doabench.features.kinds import feature_kind, item_names, storage_path
from doabench.features.spec import ObservationSpec
from doabench.features.plan import framed_audio

PREFIX = "file:"
KIND = "dataset"


@dataclass
class StoredEpisode(Episode):
    """An episode replayed without audio: ``audio`` is empty ``(M, 0)``; ``n_samples`` is the
    original length (for real-time factors); truth and features come from the file."""

    stored_n_samples: int = 0

    @property
    def n_samples(self) -> int:
        return int(self.stored_n_samples)


def resolve_file_task(task_id: str) -> TaskSpec:
    """The replay task of ``file:<path>`` (the file is opened and checked now)."""
    path = Path(task_id[len(PREFIX):]).expanduser()
    with DatasetFile(path) as f:
        origin = f.task_spec
        if not f.indices:
            raise InputError(f"{path} holds no complete episode to replay")
        return TaskSpec(
            id=task_id, version=int(origin.get("version", f.task_version)), kind=KIND,
            description=f"Replay of {len(f.indices)} episode(s) of task {f.task_id!r} stored in {path}.",
            array=str(origin.get("array", "nao")), episodes=len(f.indices), base_seed=int(origin.get("base_seed", 0)),
            frames=f.frames,
            params={"path": str(path.resolve()), "origin_task": f.task_id, "stored": list(f.items)},
            source_file=str(path),
        )


class DatasetEpisodes:
    """Episode source of a ``dataset`` task (see the module docstring).

    Scoring policy: that of the stored episodes (no ``headline`` declared: the per-recording mean
    when they are recordings, as LOCATA's, else the pooled RMSAE)."""

    Options = DatasetOptions

    def __init__(self, spec: TaskSpec) -> None:
        self.spec = spec
        self.path = Path(spec.params["path"])
        self.file = DatasetFile(self.path)
        self.indices = list(self.file.indices)
        self.delays = str(self.file.config.get("delays", "nearest"))
        #: the item that stores the recording itself (``audio``), if the file has one
        self.recording = next((i for i in self.file.items if stores_recording(i)), None)
        self.has_audio = self.recording is not None

    def __len__(self) -> int:
        return len(self.indices)

    def _index(self, j: int) -> int:
        if not 0 <= j < len(self.indices):
            raise NotFoundError(f"task {self.spec.id!r} has {len(self)} episodes; episode {j} does not exist")
        return self.indices[j]

    def _array(self, index: int) -> MicArray | None:
        g = self.file.group(index)
        if "array_positions" not in g:
            return None
        return MicArray(self.file.array.name, g["array_positions"][()], source=str(self.path))

    def _metadata(self, index: int) -> dict[str, Any]:
        meta = self.file.metadata(index)
        meta.update(replayed_from=str(self.path), episode_index=index)
        return meta

    def episode(self, j: int) -> Episode:
        index = self._index(j)
        if self.recording is None:
            raise InputError(f"{self.path} stores no audio ({', '.join(self.file.items)}); only its stored "
                             "features can be replayed")
        g = self.file.group(index)
        sample_directions = np.asarray(g["sample_directions"][()], np.float64)
        if (sample_directions.ndim != 2 or sample_directions.shape[1] != 3
                or not np.all(np.isfinite(sample_directions)) or not np.all(np.any(sample_directions, axis=1))):
            raise InputError(f"{self.path}: episode {index}: sample_directions holds non-finite or zero vectors "
                             f"(shape {sample_directions.shape}); the file is corrupt")
        return Episode(audio=g[storage_path(self.recording)][()], fs=int(g.attrs.get("fs", self.file.frames.fs)),
                       sample_vad=np.asarray(g["sample_vad"][()], bool),
                       sample_directions=sample_directions,
                       metadata=self._metadata(index), array=self._array(index))

    def stored_names(self, observations: ObservationSpec) -> list[str] | None:
        """The stored item of each observation kind, or None when one is missing."""
        names = item_names(observations.kind_names, observations.resolution)
        return names if all(n in self.file.items for n in names) else None

    def stored_features(self, j: int, observations: ObservationSpec):
        """``(episode, features {kind: (T, ...)} float32 + vad int64, truth)`` from the file, or None
        when the file cannot serve ``observations`` (then the environment renders ``episode(j)``)."""
        index = self._index(j)
        kinds, frame_spec = observations.kind_names, observations.frames
        names = self.stored_names(observations)
        same_frames = frame_spec == self.file.frames
        delays = observations.delays
        other_delays = delays not in (None, self.delays)  # kinds off the SRP grid have no delays
        if names is None or not same_frames or other_delays:
            if self.has_audio:
                return None
            why = (f"frames {frame_spec.to_dict()} (stored: {self.file.frames.to_dict()})" if not same_frames else
                   f"delays {delays!r} (stored: {self.delays!r})" if other_delays else
                   f"features {observations}")
            raise InputError(f"{self.path} stores {', '.join(self.file.items)} but the environment asks for {why}; "
                             "regenerate the file with those features or with audio")
        stored = self.file.read(index, names)
        feats = {k: np.asarray(stored[n], np.float32) for k, n in zip(kinds, names)}
        for kind in kinds:  # a framed observation (audio) is stored whole: framed here, (T, M, window)
            if feature_kind(kind).framed:
                feats[kind] = framed_audio(feats[kind], frame_spec)
        truth = self.file.truth(index)
        feats["vad"] = truth["vad"].astype(np.int64)
        g = self.file.group(index)
        array = self._array(index)
        n_mics = (array or self.file.array).n_mics
        episode = StoredEpisode(audio=np.zeros((n_mics, 0), np.float32), fs=int(g.attrs.get("fs", frame_spec.fs)),
                                sample_vad=np.zeros(0, bool), sample_directions=np.zeros((0, 3)),
                                metadata=self._metadata(index), array=array,
                                stored_n_samples=int(g.attrs.get("n_samples", 0)))
        return episode, feats, truth

    def describe(self) -> dict[str, Any]:
        return {"dataset": str(self.path), "origin_task": self.file.task_id, "stored": list(self.file.items),
                "episodes": len(self), "backend": self.file.file.attrs.get("backend")}
