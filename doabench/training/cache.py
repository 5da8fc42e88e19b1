"""A cache of noise-free reverberant trajectories for CPU training (the ``cpu`` preset).

Simulation dominates CPU training time, so each trajectory is simulated once and stored without
noise; training items add fresh white noise at the curriculum's SNR (see :mod:`.data`).

Layout of a cache folder (one per task/split/T60 range)::

    manifest.json       # what the cache holds: task, split, array, scene distribution, seeds
    00000.npz ...       # one file per trajectory, written atomically, so building is resumable

Each ``.npz`` holds ``audio`` ``(M, L)`` float16 (the reverberant signal divided by ``scale``),
``scale``, ``signal_power`` (the SNR reference power of ``audio``, i.e. already divided by
``scale**2``), ``vad`` ``(L,)`` bool, ``trajectory`` ``(S, 3)``, ``array_position`` ``(3,)`` or ``(S, 3)`` (a moving array),
``array_rotation`` ``(3, 3)`` or ``(S, 3, 3)`` (absent in caches written before arrays turned: identity),
``snr_db`` (the scene's own SNR draw, used for validation), ``t60`` and ``seed``.
Item ``i`` is the scene of seed ``episode_seed(base_seed, SPLIT_KEYS[split], i[, attempt])``;
``attempt`` counts redraws of scenes the room model rejects (e.g. an unreachable T60).
"""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from doabench.errors import ConfigError, InputError, NotFoundError
from doabench.files import atomic_path, write_json

SPLIT_KEYS = {"train": 1_000_001, "val": 1_000_002}
ITEM_KEYS = ("audio", "signal_power", "vad", "trajectory", "array_position")  # what the items read
CACHE_FORMAT = 1
MAX_ATTEMPTS = 20


def item_path(folder: Path, index: int) -> Path:
    return Path(folder) / f"{index:05d}.npz"


def cache_name(task_id: str, version: int, split: str, t60: tuple[float, float], base_seed: int) -> str:
    """Folder name of a cache: everything that changes its contents."""
    return f"{task_id}-v{version}-{split}-t60_{t60[0]:g}-{t60[1]:g}-seed{base_seed}"


def item_bytes(n_mics: int, duration_s: float, fs: int, n_points: int) -> int:
    """Bytes of one cached trajectory on disk: its float16 audio and bool VAD per sample, the
    trajectory and array positions per point (float64) and about 4 kB of ``.npz`` headers and
    scalars (a 20 s, 12-microphone item is 8,006,374 bytes)."""
    samples = int(round(duration_s * fs))
    return samples * (2 * n_mics + 1) + 2 * 3 * 8 * n_points + 4096


def write_item(path: Path, item: dict[str, Any]) -> None:
    """Write one trajectory atomically (a crash never leaves a partial file)."""
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **item)


def render_item(scene, speech, array, simulator) -> dict[str, Any]:
    """Simulate ``scene`` without noise and pack it as a cache item."""
    from doabench.acoustics.render import render_components

    r = render_components(scene, speech, array, simulator)
    scale = float(np.max(np.abs(r.reverberant))) or 1.0  # float16 keeps ~3 digits relative to the peak
    return {
        "audio": (r.reverberant / scale).astype(np.float16),
        "scale": np.float64(scale),
        "signal_power": np.float64(r.signal_power / scale**2),
        "vad": np.asarray(r.episode.sample_vad, dtype=bool),
        "trajectory": np.asarray(scene.trajectory if scene.moving_array else scene.source_positions, dtype=np.float64),
        "array_position": np.asarray(scene.array_centres, dtype=np.float64),  # (3,) or (S, 3) for a moving array
        # (3, 3) or (S, 3, 3); identity for the paper's axis-aligned array
        "array_rotation": np.eye(3) if scene.array_rotation is None else np.asarray(scene.array_rotation, np.float64),
        "snr_db": np.float64(scene.snr_db),
        "t60": np.float64(scene.room.t60),
        "seed": np.int64(scene.seed),
    }


def build_cache(folder: str | Path, n_items: int, draw_scene: Callable[[int], Any], speech, array, simulator,
                base_seed: int, split: str, manifest: dict[str, Any], log: Callable[[str], None] = print) -> Path:
    """Simulate items ``0 .. n_items - 1`` that are not in ``folder`` yet (resumable).

    ``draw_scene(seed)`` returns the scene of a seed (it may raise ConfigError for a rejected
    draw, which is retried with the next attempt's seed).
    """
    from doabench.envs.sources import episode_seed

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    manifest_path = folder / "manifest.json"
    full = {"format": CACHE_FORMAT, "split": split, "base_seed": base_seed, **manifest}
    if manifest_path.exists():
        old = json.loads(manifest_path.read_text())
        old_cmp = {k: v for k, v in old.items() if k != "n_items"}
        new_cmp = json.loads(json.dumps({k: v for k, v in full.items() if k != "n_items"}))
        if old_cmp != new_cmp:
            raise ConfigError(f"cache {folder} was built with other settings; use another --cache folder")
    write_json(manifest_path, {**full, "n_items": max(n_items, _count(folder))})
    start = time.perf_counter()
    done = 0
    for i in range(n_items):
        path = item_path(folder, i)
        if path.exists():
            continue
        for attempt in range(MAX_ATTEMPTS):
            keys = (SPLIT_KEYS[split], i) if attempt == 0 else (SPLIT_KEYS[split], i, attempt)
            try:
                scene = draw_scene(episode_seed(base_seed, *keys))
                break
            except ConfigError:
                continue
        else:
            raise ConfigError(f"cache item {i}: no valid scene in {MAX_ATTEMPTS} draws")
        write_item(path, render_item(scene, speech, array, simulator))
        done += 1
        rate = (time.perf_counter() - start) / done
        log(f"cache {folder.name}: item {i + 1}/{n_items} ({rate:.2f} s/trajectory)")
    return folder


def _count(folder: Path) -> int:
    return len(list(Path(folder).glob("[0-9]*.npz")))


class TrajectoryCache:
    """Read access to a cache folder; ``available()`` lists the item indices present."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        if not (self.folder / "manifest.json").exists():
            raise NotFoundError(f"no trajectory cache at {self.folder} (build it with `doabench train --build-cache`)")
        self.manifest = json.loads((self.folder / "manifest.json").read_text())

    def available(self) -> list[int]:
        return sorted(int(p.stem) for p in self.folder.glob("[0-9]*.npz"))

    def load(self, index: int) -> dict[str, np.ndarray]:
        """Item ``index``; a truncated or foreign file is a one-line InputError naming it."""
        path = item_path(self.folder, index)
        try:
            with np.load(path, allow_pickle=False) as z:
                item = {k: z[k] for k in z.files}
        except FileNotFoundError:
            raise NotFoundError(f"training cache item {path} is missing") from None
        except Exception as exc:  # zipfile.BadZipFile, EOFError, ValueError, ...
            raise InputError(f"training cache item {path} is damaged ({type(exc).__name__}); delete it and "
                             "rebuild with `doabench train ... --build-cache`") from None
        missing = [k for k in ITEM_KEYS if k not in item]
        if missing:
            raise InputError(f"training cache item {path} lacks {', '.join(missing)}; delete it and rebuild")
        return item
