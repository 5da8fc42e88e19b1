"""Turn a task's episode ``i`` into an :class:`EpisodeRecord`: features, truth, VAD, scene.

The episode comes from the task's episode source, so it is a pure function of (task spec, i):
the same whatever the number of episodes, the shard, the worker count or resumes. Features are
computed with :class:`doabench.features.FeatureExtractor`, exactly as :class:`DoaEnv` computes
them (one extractor per srp resolution; gcc and spectrogram share the first one's pass).
"""
from __future__ import annotations

import contextlib
from typing import Any, Iterator, Sequence

import numpy as np

from doabench.arrays import MicArray, get_array
from doabench.datasets.layout import EpisodeRecord
from doabench.datasets.schema import HALF_KINDS, TRUTH_KEYS, FeatureRequest
from doabench.envs.sources import make_episode_source
from doabench.envs.spec import TaskSpec
from doabench.errors import InputError


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
        self.sample_vad = sample_vad or any(r.kind == "audio" for r in self.requests)
        self.device = device
        self.frame_spec = spec.frames
        self.array = get_array(spec.array)
        self.source = source if source is not None else make_episode_source(spec, device=device, **source_options)
        self._extractors: dict[tuple, Any] = {}

    def __len__(self) -> int:
        return len(self.source)

    def _plan(self) -> list[tuple[tuple[str, ...], tuple[int, int]]]:
        """(kinds, resolution) of each extractor pass."""
        srp = [r.resolution for r in self.requests if r.kind == "srp"]
        other = tuple(r.kind for r in self.requests if r.kind in ("gcc", "spectrogram"))
        if not srp:
            return [(other, (16, 32))] if other else []
        passes = [(("srp", "srp_max") + other, srp[0])]
        passes += [(("srp", "srp_max"), res) for res in srp[1:]]
        return passes

    def _extractor(self, array: MicArray, kinds: tuple[str, ...], resolution: tuple[int, int]):
        from doabench.features import FeatureExtractor

        key = (array.positions.tobytes(), kinds, resolution)
        if key not in self._extractors:
            self._extractors[key] = FeatureExtractor(array, kinds=kinds, resolution=resolution, mode=self.delays,
                                                     frame_spec=self.frame_spec)
        return self._extractors[key]

    def features(self, audio: np.ndarray, sample_vad: np.ndarray, array: MicArray) -> dict[str, np.ndarray]:
        """Stored feature arrays ``{path: (T, ...)}`` of one episode's audio ``(M, L)``."""
        import torch

        out: dict[str, np.ndarray] = {}
        if not self._plan():
            return out
        x = torch.as_tensor(np.ascontiguousarray(audio), dtype=torch.float32, device=self.device)[None]
        v = torch.as_tensor(np.asarray(sample_vad, bool), device=self.device)[None]
        for kinds, res in self._plan():
            with torch.no_grad():
                feats = self._extractor(array, kinds, res)(x, v)
            r = f"{res[0]}x{res[1]}"
            for kind in kinds:
                arr = feats[kind][0].detach().cpu().numpy()
                path = f"features/{kind}_{r}" if kind in ("srp", "srp_max") else f"features/{kind}"
                dtype = np.float16 if (self.float16 and kind in HALF_KINDS) else np.float32
                out[path] = arr.astype(dtype, copy=False)
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
        if any(r.kind == "audio" for r in self.requests):
            arrays["audio"] = np.asarray(episode.audio, np.float32)
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
