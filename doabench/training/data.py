"""Training items: seeded, reproducible (audio, VAD, truth) triples for one epoch.

Item ``k`` of epoch ``e`` depends only on ``seed = episode_seed(base_seed, e, k)`` (never on a
running random state), so training is reproducible, resumable and never repeats a draw:

* :class:`CachedItems` (``cpu`` preset): the seed picks a cached noise-free trajectory, an SNR
  from the phase's range and the white noise (power ``signal_power / 10**(snr / 10)``).
* :class:`SimulatedItems` (``paper`` preset): the seed is a scene seed; the scene is drawn from the
  task's distribution with the phase's SNR range and simulated on the fly (DataLoader workers).

Every item is ``{"audio": (M, L) float32, "sample_vad": (L,) bool, "truth": (T, 3) float32,
"vad": (T,) bool}`` tensors; features are computed from the batch in torch by the trainer.
"""
from __future__ import annotations

from typing import Any, Protocol

import numpy as np
import torch
from torch.utils.data import Dataset

from doabench.geometry import resolution_text
from doabench.acoustics.trajectories import sample_directions
from doabench.envs.sources import episode_seed
from doabench.errors import ConfigError
from doabench.features.kinds import item_names
from doabench.framing import FrameSpec, frame_mean_directions, frame_vad
from doabench.training.cache import MAX_ATTEMPTS, TrajectoryCache


def frame_truth(trajectory: np.ndarray, array_position: np.ndarray, sample_vad: np.ndarray,
                frame_spec: FrameSpec, array_rotation: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame unit directions ``(T, 3)`` float32 and frame VAD ``(T,)`` bool of a cached
    trajectory (no :class:`~doabench.episode.Episode`; rendered items use its ``frame_truth``,
    which gives the same values from the same ``doabench.framing`` rules)."""
    n = len(sample_vad)
    dirs = frame_mean_directions(sample_directions(trajectory, array_position, n, array_rotation),
                                 frame_spec.window, frame_spec.hop)
    return dirs.astype(np.float32), np.asarray(frame_vad(sample_vad, frame_spec.window, frame_spec.hop), bool)


def noisy_item(item: dict[str, np.ndarray], snr_db: float, seed: int, frame_spec: FrameSpec) -> dict[str, torch.Tensor]:
    """A cached noise-free trajectory plus white noise at ``snr_db`` drawn from ``seed``."""
    audio = torch.from_numpy(item["audio"].astype(np.float32))
    g = torch.Generator().manual_seed(int(seed) & 0x7FFF_FFFF_FFFF_FFFF)
    noise_std = float(np.sqrt(item["signal_power"] / 10.0 ** (snr_db / 10.0)))
    audio = audio + noise_std * torch.randn(audio.shape, generator=g)
    truth, vad = frame_truth(item["trajectory"], item["array_position"], item["vad"], frame_spec,
                             item.get("array_rotation"))
    return {"audio": audio, "sample_vad": torch.from_numpy(item["vad"]), "truth": torch.from_numpy(truth),
            "vad": torch.from_numpy(vad)}


class CachedItems(Dataset):
    """Epoch ``epoch``'s ``n`` items drawn from the first ``n_cache`` items of a cache."""

    def __init__(self, cache: TrajectoryCache, n_cache: int, base_seed: int, epoch: int, n: int,
                 snr: tuple[float, float], frame_spec: FrameSpec) -> None:
        if n_cache < 1:
            raise ConfigError(f"trajectory cache {cache.folder} is empty")
        self.cache, self.n_cache, self.base_seed, self.epoch, self.n = cache, n_cache, base_seed, epoch, n
        self.snr, self.frame_spec = snr, frame_spec

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, k: int) -> dict[str, torch.Tensor]:
        seed = episode_seed(self.base_seed, self.epoch, k)
        rng = np.random.default_rng(seed)
        index = int(rng.integers(self.n_cache))
        snr = float(rng.uniform(*self.snr))
        return noisy_item(self.cache.load(index), snr, seed, self.frame_spec)


class SimulatedItems(Dataset):
    """Epoch ``epoch``'s ``n`` scenes simulated on the fly from ``dist`` (the paper's way)."""

    def __init__(self, dist, speech, array, simulator, base_seed: int, epoch: int, n: int,
                 frame_spec: FrameSpec) -> None:
        self.dist, self.speech, self.array, self.simulator = dist, speech, array, simulator
        self.base_seed, self.epoch, self.n, self.frame_spec = base_seed, epoch, n, frame_spec

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, k: int) -> dict[str, torch.Tensor]:
        from doabench.acoustics.render import render_scene
        from doabench.acoustics.scenes import sample_scene

        for attempt in range(MAX_ATTEMPTS):  # the room model rejects a few draws (unreachable T60)
            keys = (self.epoch, k) if attempt == 0 else (self.epoch, k, attempt)
            try:
                scene = sample_scene(self.dist, episode_seed(self.base_seed, *keys), self.speech, self.array)
                break
            except ConfigError:
                continue
        else:
            raise ConfigError(f"epoch {self.epoch} item {k}: no valid scene in {MAX_ATTEMPTS} draws")
        ep = render_scene(scene, self.speech, self.array, simulator=self.simulator)
        # The episode's own truth (its per-sample directions are the scene's, float64): the same
        # values frame_truth() computes from the trajectory, without computing them again.
        truth = ep.frame_truth(self.frame_spec)
        return {"audio": torch.from_numpy(np.ascontiguousarray(ep.audio, dtype=np.float32)),
                "sample_vad": torch.from_numpy(np.asarray(ep.sample_vad, bool)),
                "truth": torch.from_numpy(truth["directions"].astype(np.float32)),
                "vad": torch.from_numpy(truth["vad"])}


class IndexedItems(Protocol):
    """What :class:`NetworkInputs` reads from the items it wraps (torch's Dataset declares no length)."""

    def __len__(self) -> int: ...

    def __getitem__(self, k: int) -> dict[str, torch.Tensor]: ...


class NetworkInputs(Dataset):
    """``items`` with each item's audio turned into the network input by ``to_input`` (features and
    the tracker's ``network_input``), so DataLoader workers do the feature work next to the
    simulation and only ``{"input", "truth", "vad"}`` crosses to the training process.

    ``to_input(audio (M, L), sample_vad (L,)) -> input (C, T, ...)`` (no batch axis).
    """

    def __init__(self, items: IndexedItems, to_input) -> None:
        self.items, self.to_input = items, to_input

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, k: int) -> dict[str, torch.Tensor]:
        item = self.items[k]
        return {"input": self.to_input(item["audio"], item["sample_vad"]), "truth": item["truth"], "vad": item["vad"]}


class ValidationItems(Dataset):
    """Fixed validation items: cached held-out-speaker trajectories at their own scene SNR with
    noise seeded per item, identical in every epoch and every run."""

    NOISE_KEY = 2_000_003

    def __init__(self, cache: TrajectoryCache, n: int, base_seed: int, frame_spec: FrameSpec,
                 snr: tuple[float, float] | None = None) -> None:
        have = cache.available()
        self.indices = [i for i in range(n) if i in set(have)]
        if not self.indices:
            raise ConfigError(f"validation cache {cache.folder} is empty")
        self.cache, self.base_seed, self.frame_spec, self.snr = cache, base_seed, frame_spec, snr

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, j: int) -> dict[str, Any]:
        i = self.indices[j]
        item = self.cache.load(i)
        snr = float(item["snr_db"]) if self.snr is None else float(np.clip(item["snr_db"], *self.snr))
        return noisy_item(item, snr, episode_seed(self.base_seed, self.NOISE_KEY, i), self.frame_spec)


class DatasetItems(Dataset):
    """Epoch ``epoch``'s items from a dataset file made by ``doabench make-dataset``.

    The file's episodes are served in a seeded per-epoch order (``episode_seed(base_seed, e)``);
    their features are the stored ones (noise and SNR were fixed when the file was made, so the
    curriculum's SNR does not apply). Items carry ``features`` instead of ``audio``.
    """

    def __init__(self, path, kinds: tuple[str, ...], resolution: tuple[int, int] | None, base_seed: int,
                 epoch: int, n: int) -> None:
        from doabench.datasets.torch_dataset import EpisodeDataset

        res = resolution_text(resolution)
        self.kinds = kinds
        names = item_names(kinds, res)
        self.dataset = EpisodeDataset(path, features=names)
        self.names = names
        order = np.random.default_rng(episode_seed(base_seed, epoch)).permutation(len(self.dataset))
        self.order = [int(i) for i in order[: min(n, len(order))]]

    def __len__(self) -> int:
        return len(self.order)

    def __getitem__(self, k: int) -> dict[str, Any]:
        item = self.dataset[self.order[k]]
        feats = {kind: item["features"][name] for kind, name in zip(self.kinds, self.names)}
        feats["vad"] = item["vad"]
        return {"features": feats, "truth": item["directions"], "vad": item["vad"]}


def collate(items: list[dict[str, Any]]) -> dict[str, Any]:
    """Stack items into a batch; every value (and nested feature) gains a leading ``B`` axis."""
    out: dict[str, Any] = {}
    for k, v in items[0].items():
        out[k] = collate([it[k] for it in items]) if isinstance(v, dict) else torch.stack([it[k] for it in items])
    return out
