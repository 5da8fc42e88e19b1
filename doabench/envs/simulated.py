"""The ``simulated`` task kind: rooms, trajectories and speech rendered by a room simulator.

Registered through the ``doabench.task_kinds`` entry-point group (pyproject.toml), like every kind.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, Sequence

from doabench.arrays import get_array
from doabench.envs.options import SimulatedOptions
from doabench.envs.sources import episode_seed, make_speech_source
from doabench.envs.spec import TaskSpec
from doabench.episode import Episode
from doabench.errors import ConfigError, NotFoundError

if TYPE_CHECKING:
    from doabench.acoustics.scenes import Scene, SceneDistribution


class SimulatedEpisodes:
    """Episodes of a ``simulated`` task (a single distribution, a grid cell, or a whole grid).

    Scoring policy: the headline is the RMSAE pooled over every frame of every episode."""

    Options = SimulatedOptions
    headline = "pooled"

    def __init__(self, spec: TaskSpec, **options: Any) -> None:
        from doabench.acoustics.budget import check_fits, scene_fields
        from doabench.acoustics.simulators import get_simulator

        opts = SimulatedOptions(**options)
        librispeech, backend, device, scene_overrides = opts.librispeech, opts.backend, opts.device, opts.scene_overrides

        self.spec = spec
        self.array = get_array(spec.array)
        self.speech = make_speech_source(dict(spec.params.get("speech", {})), librispeech)
        # A task that names its simulator ([simulator] backend, e.g. sim-walk-pra) is rendered by
        # it: the backend is part of what the task measures, so only the default gives way to it.
        task_backend = dict(spec.params.get("simulator", {})).get("backend")
        if task_backend is not None and backend not in ("builtin", task_backend):
            raise ConfigError(f"task {spec.id!r} is rendered by the {task_backend} simulator; --backend {backend} "
                              "would change its episodes")
        self.simulator = get_simulator(task_backend or backend, device=device)
        self.device = device
        if "cells" in spec.params:  # a grid: its cells' episodes, cell after cell
            from doabench.envs.registry import get_task_spec

            cells = [get_task_spec(c) for c in spec.params["cells"]]
            self._cells = [(c.params["cell"]["index"], self._distribution(c, scene_overrides), c) for c in cells]
        else:
            cell = spec.params.get("cell", {}).get("index")
            self._cells = [(cell, self._distribution(spec, scene_overrides), spec)]
        for _, dist, cell_spec in self._cells:  # before any episode is drawn, simulated or written
            check_fits(dist, self.array.n_mics, scene_fields(f"task {cell_spec.id!r} scene"), self.simulator.name)
        self.scene_overrides = dict(scene_overrides or {})
        self._per_cell = spec.episodes // len(self._cells)

    @staticmethod
    def _distribution(spec: TaskSpec, overrides: dict[str, Any] | None) -> SceneDistribution:
        from doabench.acoustics.scenes import SceneDistribution

        return SceneDistribution.from_dict({**dict(spec.params.get("scene", {})), **(overrides or {})})

    def __len__(self) -> int:
        return self._per_cell * len(self._cells)

    def _locate(self, index: int) -> tuple[SceneDistribution, TaskSpec, int]:
        if not 0 <= index < len(self):
            raise NotFoundError(f"task {self.spec.id!r} has {len(self)} episodes; episode {index} does not exist")
        cell_index, dist, cell_spec = self._cells[index // self._per_cell]
        j = index % self._per_cell
        keys = (j,) if cell_index is None else (cell_index, j)
        return dist, cell_spec, episode_seed(self.spec.base_seed, *keys)

    def episode_seed(self, index: int) -> int:
        """The scene seed of episode ``index`` (a pure function of the spec and the cell, not of
        how many episodes a cell has)."""
        return self._locate(index)[2]

    def scene(self, index: int) -> Scene:
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

    def time_note(self, indices: Sequence[int], workers: int = 1) -> str | None:
        """One line saying how long simulating the episodes ``indices`` takes when the engine takes
        more than a minute an episode (:func:`~doabench.acoustics.budget.time_note`, from the same
        scene sizes as the memory check), else None; None too on a GPU, which the model does not
        time."""
        from doabench.acoustics.budget import scene_time, time_note

        if self.device is not None and not str(self.device).startswith("cpu"):
            return None
        per_cell = [scene_time(dist, self.array.n_mics, self.simulator.name) for _, dist, _ in self._cells]
        if any(t is None for t in per_cell):
            return None
        seconds = [per_cell[i // self._per_cell].mean for i in indices]  # type: ignore[union-attr]
        worst = max(per_cell[i // self._per_cell].worst for i in indices) if indices else None  # type: ignore[union-attr]
        return time_note(self.simulator.name, seconds, worst, workers)

    def describe(self) -> dict[str, Any]:
        return {"simulator": self.simulator.name, "simulator_versions": self.simulator.versions(),
                "speech": dict(self.spec.params.get("speech", {})), "scene_overrides": self.scene_overrides}



def speed_statistics(spec: TaskSpec) -> dict[str, float]:
    """How fast a simulated task's talkers move, seen from the array: percentiles (10, 50, 90) over
    all trajectory points of all its episodes of the angular speed in deg/s, and the median of the
    per-episode medians. Geometry only (no speech, no simulation): a few seconds for 360 episodes."""
    import numpy as np

    from doabench.acoustics.scenes import sample_scene
    from doabench.envs.registry import get_task_spec

    cells = [get_task_spec(c) for c in spec.params["cells"]] if "cells" in spec.params else [spec]
    per_cell = spec.episodes // len(cells)
    speeds, medians = [], []
    for cell in cells:
        dist = SimulatedEpisodes._distribution(cell, None)
        index = cell.params.get("cell", {}).get("index")
        for j in range(per_cell):
            keys = (j,) if index is None else (index, j)
            try:
                v = sample_scene(dist, episode_seed(spec.base_seed, *keys)).speed_deg_s
            except ConfigError:  # a draw the training data redraws (a moving array too near the talker)
                continue
            speeds.append(v)
            medians.append(float(np.median(v)))
    allv = np.concatenate(speeds)
    p10, p50, p90 = (float(x) for x in np.percentile(allv, [10, 50, 90]))
    return {"p10": p10, "median": p50, "p90": p90, "episode_median": float(np.median(medians))}
