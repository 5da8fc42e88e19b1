"""Turn a task's episode ``i`` into an :class:`EpisodeRecord`: features, truth, VAD, scene.

The episode comes from the task's episode source, so it is a pure function of (task spec, i):
the same whatever the number of episodes, the shard, the worker count or resumes. Features are
computed by the same :class:`doabench.features.ObservationPlan` as :class:`DoaEnv` uses (one
extractor pass per srp resolution; gcc and spectrogram share the first one's pass).
"""
from __future__ import annotations

import contextlib
from typing import Any, Iterator, Sequence

import numpy as np

from doabench.arrays import MicArray, get_array
from doabench.datasets.layout import EpisodeRecord
from doabench.datasets.schema import TRUTH_KEYS, FeatureRequest
from doabench.envs.sources import make_episode_source
from doabench.envs.spec import TaskSpec
from doabench.errors import ConfigError, InputError
from doabench.features.kinds import feature_kind, storage_path
from doabench.features.plan import ObservationPlan
from doabench.features.spec import ObservationSpec
from doabench.framing import FrameSpec


@contextlib.contextmanager
def one_thread() -> Iterator[None]:
    """Run torch on one thread: multi-threaded FFTs and reductions sum in another order, so the
    same episode computed with 1 or 2 threads differs in the last bits. One thread everywhere makes
    a dataset bitwise identical whatever ``--workers`` (parallelism comes from processes)."""
    import torch

    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def _map_grid(request: FeatureRequest) -> tuple[int, int]:
    """The SRP grid of a map request (``parse_feature`` always gives one)."""
    if request.resolution is None:
        raise ConfigError(f"feature {request.kind!r} needs a resolution, e.g. {request.kind}:16x32")
    return request.resolution


def requests_plan(requests: Sequence[FeatureRequest], array: MicArray, frame_spec: FrameSpec, delays: str = "nearest"
                  ) -> ObservationPlan | None:
    """The observation plan of the computed features of ``requests`` (None when only audio is
    stored: then nothing is computed): the requested kinds on the SRP grid (srp, a plug-in map) and
    the kinds they come with (srp_max) on every requested grid, the other computed kinds (gcc,
    spectrogram, a plug-in's) once. A dataset stores the items its requests name
    (:meth:`FeatureRequest.stored`), not every kind on every grid."""
    maps = [r for r in requests if feature_kind(r.kind).on_grid]
    grids = list(dict.fromkeys(_map_grid(r) for r in maps))
    on_grid = tuple(dict.fromkeys(k for r in maps for k in (r.kind, *feature_kind(r.kind).comes_with)))
    once = tuple(r.kind for r in requests if not feature_kind(r.kind).on_grid and feature_kind(r.kind).compute is not None)
    if not on_grid + once:
        return None
    spec = ObservationSpec.of(on_grid + once, grids[0] if grids else None, frame_spec, delays)
    return spec.plan(array, grids or None)


class EpisodeComputer:
    """Computes the records of one task's episodes for a fixed feature request.

    ``requests``: the features to store; ``float16``: store srp/gcc/spectrogram maps as float16;
    ``delays``: the extractor's delay mode; ``sample_vad``: also store the per-sample VAD (always
    stored with audio); ``source_options``: go to the task's episode source (librispeech, backend),
    unless an already built ``source`` is given.
    """

    def __init__(self, spec: TaskSpec, requests: Sequence[FeatureRequest], float16: bool = False,
                 delays: str = "nearest", sample_vad: bool = False, device: str | None = None,
                 source: Any = None, **source_options: Any) -> None:
        self.spec = spec
        self.requests = tuple(requests)
        self.float16 = float16
        self.delays = delays
        self.sample_vad = sample_vad or any(r.framed for r in self.requests)
        self.device = device
        self.frame_spec = spec.frames
        self.array = get_array(spec.array)
        self.source = source if source is not None else make_episode_source(spec, device=device, **source_options)
        self.plan = requests_plan(self.requests, self.array, self.frame_spec, delays)
        #: the computed items the requests store (a plan computes its map kinds on every grid)
        self.stored = {name for r in self.requests if not r.framed for name in r.stored()}

    def __len__(self) -> int:
        return len(self.source)

    def features(self, audio: np.ndarray, sample_vad: np.ndarray, array: MicArray) -> dict[str, np.ndarray]:
        """Stored feature arrays ``{path: (T, ...)}`` of one episode's audio ``(M, L)``."""
        if self.plan is None:
            return {}
        items = self.plan.compute(audio, sample_vad, array, self.device)
        out: dict[str, np.ndarray] = {}
        for name in (n for n in self.plan.names() if n in self.stored):
            dtype = np.float16 if (self.float16 and feature_kind(name.partition(":")[0]).half) else np.float32
            out[storage_path(name)] = items[name].astype(dtype, copy=False)
        return out

    def compute(self, index: int) -> EpisodeRecord:
        """The record of episode ``index``, computed with one torch thread (see :func:`one_thread`)."""
        with one_thread():
            return self._compute(index)

    def _compute(self, index: int) -> EpisodeRecord:
        episode = self.source.episode(index)
        array = episode.array or self.array
        if episode.n_mics != array.n_mics:
            raise InputError(f"episode {index} of {self.spec.id!r} has {episode.n_mics} channels but array "
                             f"{array.name!r} has {array.n_mics} microphones")
        arrays = self.features(episode.audio, episode.sample_vad, array)
        truth = episode.frame_truth(self.frame_spec)
        n = len(truth["directions"])
        for path, arr in arrays.items():
            if len(arr) != n:
                raise RuntimeError(f"{path} has {len(arr)} frames, truth has {n}")  # a doabench bug
        for key in TRUTH_KEYS:
            arrays[f"truth/{key}"] = np.asarray(truth[key], np.float64)
        arrays["vad"] = np.asarray(truth["vad"], bool)
        recording = [r for r in self.requests if r.framed]  # the recording itself, stored whole
        for r in recording:
            arrays[storage_path(r.name)] = np.asarray(episode.audio, np.float32)
        if recording:
            arrays["sample_directions"] = np.asarray(episode.sample_directions, np.float32)
        if self.sample_vad:
            arrays["sample_vad"] = np.asarray(episode.sample_vad, bool)
        if episode.array is not None:
            arrays["array_positions"] = np.asarray(episode.array.positions, np.float64)
        metadata = dict(episode.metadata)
        metadata.setdefault("episode_index", int(index))
        seed = metadata.get("seed", (metadata.get("scene") or {}).get("seed"))
        attrs = {"n_frames": n, "n_samples": episode.n_samples, "fs": int(episode.fs)}
        if seed is not None:
            attrs["seed"] = int(seed)
        return EpisodeRecord(int(index), arrays, attrs, metadata)

    def describe(self) -> dict[str, Any]:
        return dict(self.source.describe())
