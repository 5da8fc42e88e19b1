"""Episode sources: what turns a task spec and an episode index into an :class:`Episode`.

Each task ``kind`` has a factory registered with :func:`register_task_kind`; the factory gets the
spec and the run-time options (corpus paths, simulator backend, device) and returns an object
with ``__len__``, ``episode(index) -> Episode`` and ``describe() -> dict``. Episode ``i`` of a task
is a pure function of the spec and ``i``: the seed of a simulated episode is derived from
``(base_seed, cell, i)`` with numpy's SeedSequence, never from a running random state.
"""
from __future__ import annotations

import os
from typing import Any, Callable, Protocol

import numpy as np

from doabench.arrays import get_array
from doabench.envs.spec import TaskSpec
from doabench.episode import Episode
from doabench.errors import ConfigError, NotFoundError


class EpisodeSource(Protocol):
    def __len__(self) -> int: ...
    def episode(self, index: int) -> Episode: ...
    def describe(self) -> dict[str, Any]: ...


_KINDS: dict[str, Callable[..., EpisodeSource]] = {}


def register_task_kind(kind: str, factory: Callable[..., EpisodeSource]) -> None:
    """Register the episode-source factory ``factory(spec, **options)`` of a task kind."""
    _KINDS[kind] = factory


def make_episode_source(spec: TaskSpec, **options: Any) -> EpisodeSource:
    if spec.kind not in _KINDS and spec.kind == "locata":
        import doabench.locata  # noqa: F401  (registers the kind)
    if spec.kind not in _KINDS:
        raise ConfigError(f"task {spec.id!r}: unknown kind {spec.kind!r} (known: {', '.join(sorted(_KINDS))})")
    return _KINDS[spec.kind](spec, **options)


def episode_seed(base_seed: int, *keys: int) -> int:
    """A 63-bit seed that depends only on ``base_seed`` and ``keys`` (cell, episode index)."""
    state = np.random.SeedSequence([int(base_seed), *map(int, keys)]).generate_state(2, np.uint32)
    return int((int(state[0]) << 31) ^ int(state[1]))


def make_speech_source(speech: dict[str, Any], librispeech: str | None = None):
    """The speech source a task's ``[speech]`` section asks for."""
    from doabench.acoustics import speech as speech_mod

    corpus = speech.get("corpus", "embedded")
    if corpus == "embedded":
        return speech_mod.EmbeddedSpeechSource()
    if corpus == "librispeech":
        root = librispeech or os.environ.get("DOABENCH_LIBRISPEECH")
        if not root:
            raise NotFoundError(
                f"this task needs LibriSpeech {speech.get('subset', '')}: pass --librispeech PATH (Python: "
                "librispeech=PATH) or set "
                "DOABENCH_LIBRISPEECH (get it with `doabench data download librispeech --subset "
                f"{speech.get('subset', 'test-clean')}`)")
        kwargs = {k: v for k, v in speech.items() if k not in ("corpus", "subset")}
        return speech_mod.LibriSpeechSource(root, speech.get("subset", "test-clean"), **kwargs)
    raise ConfigError(f"unknown speech corpus {corpus!r} (use embedded or librispeech)")


class SimulatedEpisodes:
    """Episodes of a ``simulated`` task (a single distribution, a grid cell, or a whole grid)."""

    def __init__(self, spec: TaskSpec, librispeech: str | None = None, backend: str = "builtin",
                 device: str | None = None, scene_overrides: dict[str, Any] | None = None, **_: Any) -> None:
        """``scene_overrides`` replaces scene-distribution fields of every cell (e.g.
        ``{"duration_s": 3}`` for quick checks); results record it, and it changes the episodes."""
        from doabench.acoustics.simulators import get_simulator

        self.spec = spec
        self.array = get_array(spec.array)
        self.speech = make_speech_source(dict(spec.params.get("speech", {})), librispeech)
        self.simulator = get_simulator(backend, device=device)
        self.device = device
        if "cells" in spec.params:  # a grid: its cells' episodes, cell after cell
            from doabench.envs.registry import get_task_spec

            cells = [get_task_spec(c) for c in spec.params["cells"]]
            self._cells = [(c.params["cell"]["index"], self._distribution(c, scene_overrides), c) for c in cells]
        else:
            cell = spec.params.get("cell", {}).get("index")
            self._cells = [(cell, self._distribution(spec, scene_overrides), spec)]
        self.scene_overrides = dict(scene_overrides or {})
        self._per_cell = spec.episodes // len(self._cells)

    @staticmethod
    def _distribution(spec: TaskSpec, overrides: dict[str, Any] | None):
        from doabench.acoustics.scenes import SceneDistribution

        return SceneDistribution.from_dict({**dict(spec.params.get("scene", {})), **(overrides or {})})

    def __len__(self) -> int:
        return self._per_cell * len(self._cells)

    def _locate(self, index: int):
        if not 0 <= index < len(self):
            raise NotFoundError(f"task {self.spec.id!r} has {len(self)} episodes; episode {index} does not exist")
        cell_index, dist, cell_spec = self._cells[index // self._per_cell]
        j = index % self._per_cell
        keys = (j,) if cell_index is None else (cell_index, j)
        return dist, cell_spec, episode_seed(self.spec.base_seed, *keys)

    def scene(self, index: int):
        from doabench.acoustics.scenes import sample_scene

        dist, _, seed = self._locate(index)
        return sample_scene(dist, seed, self.speech, array=self.array)

    def episode(self, index: int) -> Episode:
        from doabench.acoustics.render import render_scene

        _, cell_spec, seed = self._locate(index)
        episode = render_scene(self.scene(index), self.speech, self.array, simulator=self.simulator,
                               device=self.device)
        episode.metadata.update({"task": cell_spec.id, "episode_index": index, "seed": seed})
        return episode

    def describe(self) -> dict[str, Any]:
        return {"simulator": self.simulator.name, "simulator_versions": self.simulator.versions(),
                "speech": dict(self.spec.params.get("speech", {})), "scene_overrides": self.scene_overrides}


register_task_kind("simulated", SimulatedEpisodes)
