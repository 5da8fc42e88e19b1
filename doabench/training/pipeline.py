"""Wiring between a task spec, a recipe and the training data: scene distributions, speaker-split
speech sources and the trajectory caches of the ``cpu`` preset."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

from doabench.acoustics.scenes import SceneDistribution
from doabench.envs.spec import TaskSpec
from doabench.training.cache import build_cache, cache_name
from doabench.training.recipes import Recipe
from doabench.training.splits import split_speech_source

DEFAULT_CACHE_ROOT = Path("runs/cache")


def scene_distribution(spec: TaskSpec, recipe: Recipe) -> SceneDistribution:
    """The task's scene distribution with the recipe's duration and T60 override."""
    dist = SceneDistribution.from_dict(dict(spec.params.get("scene", {})))
    changes: dict[str, Any] = {"duration_s": recipe.duration_s}
    if recipe.t60 is not None:
        changes["t60"] = tuple(recipe.t60)
    return dist.replace(**changes)


def check_memory(spec: TaskSpec, recipe: Recipe, backend: str = "builtin") -> None:
    """Refuse training scenes whose simulation on the engine ``backend`` would need more memory
    than this machine has (:func:`~doabench.acoustics.budget.check_fits`), before any cache or run
    folder is written."""
    from doabench.acoustics.budget import check_fits, scene_fields
    from doabench.arrays import get_array

    check_fits(scene_distribution(spec, recipe), get_array(spec.array).n_mics,
               scene_fields(f"task {spec.id!r} training scene"), backend)


def simulation_note(spec: TaskSpec, recipe: Recipe, backend: str, n_trajectories: int, workers: int = 1,
                    group: str | None = None) -> str | None:
    """How long simulating ``n_trajectories`` training scenes takes on the engine ``backend`` when
    it takes more than a minute a scene (:func:`~doabench.acoustics.budget.time_note`, from the
    same scene sizes as :func:`check_memory`), else None."""
    from doabench.acoustics.budget import scene_time, time_note
    from doabench.arrays import get_array

    timing = scene_time(scene_distribution(spec, recipe), get_array(spec.array).n_mics, backend)
    if timing is None or n_trajectories < 1:
        return None
    return time_note(backend, [timing.mean] * n_trajectories, timing.worst, workers, "trajectory", group)


def cache_size_text(spec: TaskSpec, recipe: Recipe, n_items: int) -> str:
    """About how much disk ``n_items`` cached trajectories of ``spec`` take: ``about 240 MB``."""
    from doabench.arrays import get_array
    from doabench.training.cache import item_bytes

    dist = scene_distribution(spec, recipe)
    total = n_items * item_bytes(get_array(spec.array).n_mics, dist.duration_s, dist.fs, dist.n_points)
    return f"about {total / 1e9:.3g} GB" if total >= 1e9 else f"about {total / 1e6:.3g} MB"


def speech_for_split(spec: TaskSpec, split: str, librispeech: str | None, fraction: float):
    """The task's speech source restricted to the ``train`` or ``val`` speakers."""
    from doabench.envs.sources import make_speech_source

    return split_speech_source(make_speech_source(dict(spec.params.get("speech", {})), librispeech), split, fraction)


def cache_folder(root: str | Path, spec: TaskSpec, recipe: Recipe, split: str) -> Path:
    dist = scene_distribution(spec, recipe)
    return Path(root) / cache_name(spec.id, spec.version, split, dist.t60, spec.base_seed)


def ensure_cache(root: str | Path, spec: TaskSpec, recipe: Recipe, split: str, n_items: int,
                 librispeech: str | None, simulator: str = "builtin",
                 log: Callable[[str], None] = print) -> Path:
    """Simulate the missing items of a split's cache (resumable); returns its folder."""
    from doabench.acoustics.scenes import sample_scene
    from doabench.acoustics.simulators import get_simulator
    from doabench.arrays import get_array

    check_memory(spec, recipe, simulator)
    dist = scene_distribution(spec, recipe)
    folder = cache_folder(root, spec, recipe, split)
    missing = n_items - len(list(folder.glob("[0-9]*.npz")))
    if missing > 0:  # where, how much disk and (a slow engine) how long, before the first trajectory
        of = f"{missing} of {n_items}" if missing < n_items else f"{n_items}"
        name = "validation" if split == "val" else "training"
        log(f"building the {name} cache in {folder}: {of} trajectories of {dist.duration_s:g} s to simulate, "
            f"{cache_size_text(spec, recipe, missing)} on disk (kept there for later runs)")
        if note := simulation_note(spec, recipe, simulator, missing):
            log(note)
    speech = speech_for_split(spec, split, librispeech, recipe.val_speaker_fraction)
    array = get_array(spec.array)
    manifest = {"task": spec.id, "task_version": spec.version, "array": array.name,
                "scene": dist.to_dict(), "speech": dict(spec.params.get("speech", {})),
                "speaker_split": {"split": split, "val_fraction": recipe.val_speaker_fraction,
                                  "speakers": sorted(getattr(speech, "speakers", []))},
                "simulator": simulator}
    return build_cache(folder, n_items,
                       lambda seed: sample_scene(dist, seed, speech, array), speech, array,
                       get_simulator(simulator), spec.base_seed, split, manifest, log)
