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
    speech = speech_for_split(spec, split, librispeech, recipe.val_speaker_fraction)
    array = get_array(spec.array)
    manifest = {"task": spec.id, "task_version": spec.version, "array": array.name,
                "scene": dist.to_dict(), "speech": dict(spec.params.get("speech", {})),
                "speaker_split": {"split": split, "val_fraction": recipe.val_speaker_fraction,
                                  "speakers": sorted(getattr(speech, "speakers", []))},
                "simulator": simulator}
    return build_cache(cache_folder(root, spec, recipe, split), n_items,
                       lambda seed: sample_scene(dist, seed, speech, array), speech, array,
                       get_simulator(simulator), spec.base_seed, split, manifest, log)
