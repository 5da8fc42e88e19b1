"""``make-dataset --engine ray``: episodes as Ray tasks, on a cluster or a local Ray instance.

The journal of :mod:`doabench.datasets.generate` is unchanged: ``workers`` Ray actors (one CPU
each) each hold an :class:`~doabench.datasets.compute.EpisodeComputer`; an actor computes
episode ``i``, writes its part file with :func:`~doabench.datasets.layout.write_part` into a
folder of its own node and sends the file's bytes back. The driver stores them in
``<out>.parts/NNNNNN.h5`` atomically (tmp file, fsync, rename), exactly as a local worker
would, so the nodes need no shared file system, a killed run resumes from the parts the driver
received, and the assembled file has the same bytes in every dataset as a single-process run
(episode ``i`` is a pure function of the task and ``i``, computed with one torch thread).
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any, Callable, Sequence

from doabench.datasets.layout import write_part
from doabench.datasets.schema import FeatureRequest, episode_name
from doabench.envs.spec import TaskSpec
from doabench.ray_support import cluster_cpus, ray_session, unwrap
from doabench.files import atomic_path

# Tasks queued per actor: one running, one waiting, so an actor never idles between episodes.
IN_FLIGHT_PER_WORKER = 2


class EpisodeWorker:
    """A Ray actor's state: the episode computer of one dataset configuration."""

    def __init__(self, spec: TaskSpec, requests: Sequence[FeatureRequest], computer_kwargs: dict[str, Any],
                 compression: str, tag: str) -> None:
        import torch

        from doabench.datasets.compute import EpisodeComputer

        torch.set_num_threads(1)  # as the local workers: bitwise the same episodes
        self.computer = EpisodeComputer(spec, requests, **computer_kwargs)
        self.compression, self.tag = compression, tag

    def compute(self, index: int) -> tuple[int, bytes]:
        with tempfile.TemporaryDirectory(prefix="doabench-part-") as tmp:
            path = write_part(Path(tmp), self.computer.compute(index), self.compression, self.tag)
            return index, path.read_bytes()


def store_part(folder: Path, index: int, data: bytes) -> Path:
    """Write a part received from a worker into the journal atomically (as :func:`write_part`)."""
    name = episode_name(index)
    final = folder / f"{name}.h5"
    with atomic_path(final, tmp=folder / f".{name}.{os.getpid()}.tmp") as tmp:
        tmp.write_bytes(data)
    return final


def run_ray(spec: TaskSpec, requests, computer_kwargs: dict[str, Any], todo: list[int], folder: Path,
            compression: str, workers: int | None, done: Callable[[int], None], tag: str = "",
            address: str | None = None) -> int:
    """Compute the episodes ``todo`` on Ray, storing each part as it arrives; returns the actor count.

    ``workers``: actors (default: every CPU of the cluster at ``address``, else 1)."""
    with ray_session(address, workers) as ray:
        n = int(workers) if workers else cluster_cpus(ray)
        n = max(1, min(n, len(todo)))
        actor_cls = ray.remote(num_cpus=1)(EpisodeWorker)
        actors = [actor_cls.remote(spec, requests, computer_kwargs, compression, tag) for _ in range(n)]
        queue = list(todo)
        owner: dict[Any, Any] = {}

        def submit(actor) -> None:
            index = queue.pop(0)
            owner[actor.compute.remote(index)] = actor

        try:
            for actor in actors:
                for _ in range(IN_FLIGHT_PER_WORKER):
                    if queue:
                        submit(actor)
            while owner:
                ready, _ = ray.wait(list(owner), num_returns=1)
                ref = ready[0]
                actor = owner.pop(ref)
                try:
                    index, data = ray.get(ref)
                except Exception as exc:
                    raise unwrap(exc) from None
                store_part(folder, index, data)
                done(index)
                if queue:
                    submit(actor)
        finally:  # on an error or Ctrl-C: stop the episodes still running (their parts are not needed)
            for actor in actors:
                ray.kill(actor)
        return n
