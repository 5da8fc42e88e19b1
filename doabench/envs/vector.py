"""Vector environments that split a task's episodes across their sub-environments.

``gymnasium.make_vec`` gives every sub-environment the same keyword arguments and the same reset
``options``, so without an ``episode`` option each one draws episodes from its own RNG, with
replacement: two workers may run the same episode and others none. :func:`make_vec` instead
hands sub-environment ``k`` of ``n`` the episodes ``k, k + n, k + 2n, ...`` (its share, the
``episodes`` argument of :class:`~doabench.envs.env.DoaEnv`); each ``reset()`` without an
``episode`` option serves the next episode of the share, so one pass over all sub-environments
runs every episode exactly once.
"""
from __future__ import annotations

import functools
from typing import Any, Sequence

import gymnasium

from doabench.envs.registry import get_task_spec
from doabench.envs.spec import TaskSpec
from doabench.errors import InputError

VECTORIZATION_MODES = ("async", "sync")


def split_episodes(episodes: int | Sequence[int], num_envs: int) -> list[list[int]]:
    """Round-robin shares: ``split_episodes(5, 2) == [[0, 2, 4], [1, 3]]``. ``episodes`` is a
    count (episodes ``0 .. n-1``) or the indices to split."""
    indices = list(range(episodes)) if isinstance(episodes, int) else [int(i) for i in episodes]
    if num_envs < 1:
        raise InputError(f"num_envs must be at least 1, got {num_envs}")
    if len(indices) < num_envs:
        raise InputError(f"{num_envs} sub-environments for {len(indices)} episodes: each needs at least one "
                         "(use fewer sub-environments)")
    return [indices[k::num_envs] for k in range(num_envs)]


def make_vec(task: str | TaskSpec, num_envs: int, vectorization_mode: str = "async",
             episodes: Sequence[int] | None = None, vector_kwargs: dict[str, Any] | None = None,
             **env_kwargs: Any) -> gymnasium.vector.VectorEnv:
    """A vector environment over ``task`` whose ``num_envs`` sub-environments share its episodes
    (all of them, or the indices in ``episodes``) without repetition (:func:`split_episodes`).

    ``env_kwargs`` are :class:`~doabench.envs.env.DoaEnv`'s (``features``, ``resolution``, source
    options...); ``vector_kwargs`` go to ``gymnasium.vector.AsyncVectorEnv`` (e.g.
    ``{"context": "spawn"}``) or ``SyncVectorEnv``. ``info["episode"]`` of a reset names the
    episode each sub-environment started and ``info["repeat"]`` is 0 on its first pass through
    its share (a sub-environment that finishes its share early is auto-reset into a second pass
    while the others finish: leave out the episodes with ``repeat > 0``).
    ``envs.call("episode_share")`` lists each sub-environment's episodes."""
    if vectorization_mode not in VECTORIZATION_MODES:
        raise InputError(f"vectorization_mode must be one of {', '.join(VECTORIZATION_MODES)}, "
                         f"not {vectorization_mode!r}")
    spec = get_task_spec(task)
    if episodes is None:
        from doabench.envs.env import DoaEnv

        # The count comes from the episode source (LOCATA: the recordings found), not the spec alone.
        probe = DoaEnv(spec, **env_kwargs)
        episodes = range(probe.n_episodes)
        probe.close()
    shares = split_episodes(episodes, num_envs)
    try:
        env_spec = gymnasium.spec(spec.gym_id)
    except gymnasium.error.Error:  # a TaskSpec that was never registered: the same entry point
        env_spec = gymnasium.envs.registration.EnvSpec(id=spec.gym_id, entry_point="doabench.envs.env:DoaEnv")
    # The spec itself travels to the workers (not its id), so a task registered at run time works
    # in spawned workers too.
    fns = [functools.partial(gymnasium.make, env_spec, task=spec, episodes=share, **env_kwargs) for share in shares]
    if vectorization_mode == "sync":
        return gymnasium.vector.SyncVectorEnv(fns, **(vector_kwargs or {}))
    return gymnasium.vector.AsyncVectorEnv(fns, **(vector_kwargs or {}))
