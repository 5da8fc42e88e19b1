"""Data-parallel training: ``torchrun --standalone --nproc-per-node N -m doabench train ...``.

Every rank builds the same :class:`~doabench.training.trainer.Trainer` (same seed, so the same
initial weights; DDP also broadcasts rank 0's), then:

* **data**: each global batch of the epoch (the recipe's batch size, items ``k`` in index order as
  in one process) is cut into ``N`` contiguous slices and rank ``r`` simulates (or loads) only
  its slice, in its own DataLoader workers. Items are seeded by ``(base_seed, epoch, k)``, so the
  union of the slices is exactly the one-process batch.
* **gradients**: the network is wrapped in ``DistributedDataParallel`` (gloo on CPU, NCCL on
  CUDA). Its communication hook weights rank ``r``'s gradient by ``n_r / n`` (its share of the
  batch's items) before summing, which is the gradient of the mean loss over the whole batch,
  also for a last batch that does not split evenly (a rank without an item computes one with
  weight 0). So N processes train the same weights as one process with the same global batch,
  to float rounding (the sum runs in another order).
* **writing**: rank 0 alone writes the checkpoint (format unchanged, :mod:`.checkpoint`),
  ``log.csv``, ``loss.png``, ``config.json``, ``distributed.json`` and the log lines; the
  logged train loss is the all-reduced batch loss, as one process logs it.
* **resume**: every rank reads the run's checkpoint (``--resume``), so a run killed at any point
  continues after its last finished epoch, with the same or another number of processes.

Batch-norm statistics are per rank (a slice of the batch), as usual with DDP; networks with
batch norm therefore train close to, not bitwise like, one process.
"""
from __future__ import annotations

import dataclasses
import datetime as _dt
import gc
import json
import os
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np
import torch

from doabench.errors import ConfigError


def is_distributed_launch() -> bool:
    """True in a process started by torchrun (or anything that sets its variables) with N > 1."""
    return int(os.environ.get("WORLD_SIZE", "1")) > 1


def launch_env() -> tuple[int, int, int]:
    """``(rank, world_size, local_rank)`` from torchrun's environment variables."""
    try:
        rank, world = int(os.environ["RANK"]), int(os.environ["WORLD_SIZE"])
        local = int(os.environ.get("LOCAL_RANK", rank))
    except (KeyError, ValueError):
        raise ConfigError("data-parallel training needs RANK and WORLD_SIZE (start it with torchrun "
                          "--nproc-per-node N -m doabench train ...)") from None
    return rank, world, local


def rank_batches(n_items: int, batch_size: int, rank: int, world: int) -> tuple[list[list[int]], list[float]]:
    """This rank's item indices for each global batch of ``batch_size`` over ``n_items`` items and
    the weight ``n_r / n`` of its gradient (0 for a stand-in item when a batch has fewer items
    than ranks)."""
    batches, weights = [], []
    for start in range(0, n_items, batch_size):
        items = np.arange(start, min(start + batch_size, n_items))
        mine = np.array_split(items, world)[rank]
        if len(mine):
            batches.append([int(i) for i in mine])
            weights.append(len(mine) / len(items))
        else:  # every rank must take part in the all-reduce: a stand-in item that weighs nothing
            batches.append([int(items[0])])
            weights.append(0.0)
    return batches, weights


class _WeightedLoader:
    """This rank's batches; sets the gradient weight of each batch before the step sees it."""

    def __init__(self, loader, weights: Sequence[float], state: "DataParallel") -> None:
        self.loader, self.weights, self.state = loader, list(weights), state

    def __len__(self) -> int:
        return len(self.weights)

    def __iter__(self):
        for weight, batch in zip(self.weights, self.loader):
            self.state.weight = weight
            yield batch


def _weighted_allreduce(state: "DataParallel", bucket):
    """DDP communication hook: sum of ``weight_r * grad_r`` over the ranks (the default hook averages)."""
    import torch.distributed as dist

    buffer = bucket.buffer()
    buffer.mul_(state.weight)
    future = dist.all_reduce(buffer, op=dist.ReduceOp.SUM, async_op=True).get_future()
    return future.then(lambda fut: fut.value()[0])


@dataclass
class DataParallel:
    """What a Trainer holds as ``trainer.dist`` in a data-parallel run."""

    rank: int
    world: int
    local_rank: int
    backend: str
    weight: float = 1.0

    def loader(self, trainer, items, batch_size: int):
        """This rank's share of the epoch's batches (the trainer's DataLoader settings otherwise)."""
        from torch.utils.data import DataLoader

        from doabench.training.epoch_data import loader_options

        batches, weights = rank_batches(len(items), int(batch_size), self.rank, self.world)
        loader = DataLoader(items, batch_sampler=batches, **loader_options(trainer.workers))
        return _WeightedLoader(loader, weights, self)


def _per_rank_workers(trainer, world: int) -> int:
    """DataLoader workers per rank: the trainer's, capped so N ranks do not oversubscribe the cores."""
    from doabench.training.epoch_data import available_cores

    if trainer.workers <= 0 or trainer.options.workers is not None:
        return trainer.workers  # none, or what the user asked for
    return max(1, min(trainer.workers, available_cores() // world))


def setup(trainer, rank: int, world: int, local_rank: int, backend: str) -> DataParallel:
    """Turn a constructed Trainer into rank ``rank`` of a data-parallel run (process group initialised)."""
    import torch.distributed as dist
    from torch.nn.parallel import DistributedDataParallel

    state = DataParallel(rank, world, local_rank, backend)
    trainer.workers = _per_rank_workers(trainer, world)
    device_ids = [trainer.device.index] if trainer.device.type == "cuda" else None
    ddp = DistributedDataParallel(trainer.network, device_ids=device_ids)
    ddp.register_comm_hook(state, _weighted_allreduce)
    trainer.train_forward = torch.compile(ddp) if trainer.options.compile else ddp
    one_step = trainer.train_step

    def train_step(batch) -> float:
        """The step, then the batch's loss over every rank (what one process would log)."""
        loss = one_step(batch)
        t = torch.tensor([loss * state.weight], dtype=torch.float64, device=trainer.device)
        dist.all_reduce(t, op=dist.ReduceOp.SUM)
        return float(t.item())

    trainer.train_step = train_step
    trainer.dist = state
    return state


def run_distributed(options, log: Callable[[str], None] = print, timeout_s: float = 7200.0,
                    **trainer_kwargs: Any) -> list[dict[str, Any]]:
    """Rank ``$RANK`` of a data-parallel run of ``options`` (a TrainOptions); rank 0 returns the
    history, the others an empty list. ``trainer_kwargs`` go to :class:`Trainer` (tests inject a
    tracker and caches). ``timeout_s`` bounds every collective, including the wait for rank 0
    to build a missing validation cache (build big ones first with ``--build-cache``)."""
    import torch.distributed as dist

    from doabench.training.trainer import Trainer

    rank, world, local_rank = launch_env()
    cuda = str(options.device).startswith("cuda")
    if cuda:
        if not torch.cuda.is_available():
            raise ConfigError("--device cuda requested but torch has no CUDA device here")
        torch.cuda.set_device(local_rank)
        options = dataclasses.replace(options, device=f"cuda:{local_rank}")
    backend = "nccl" if cuda else "gloo"
    if rank != 0:
        options = dataclasses.replace(options, progress=False)
        log = lambda message: None  # noqa: E731 - rank 0 speaks for the run
    dist.init_process_group(backend, rank=rank, world_size=world, timeout=_dt.timedelta(seconds=timeout_s))
    trainer = state = None
    try:
        trainer = Trainer(options, log=log, **trainer_kwargs)
        state = setup(trainer, rank, world, local_rank, backend)
        if rank == 0:  # a missing validation cache is simulated once, by rank 0, while the others wait
            trainer.data.val_cache()
        # Every rank has read the run folder (a resume checkpoint, or none) before rank 0 writes it.
        dist.barrier()
        if rank == 0:
            from doabench.files import write_json

            trainer.out.mkdir(parents=True, exist_ok=True)
            write_json(trainer.out / "distributed.json",
                       {"world_size": world, "backend": backend, "workers_per_rank": trainer.workers,
                        "global_batch_sizes": [p.batch_size for p in trainer.recipe.phases],
                        "torch": torch.__version__})
            log(f"data-parallel training: {world} processes ({backend}), {trainer.workers} data workers each")
        history = trainer.run()
        dist.barrier()  # rank 0's last checkpoint is written before any rank leaves
        return history if rank == 0 else []
    finally:
        # Free DDP (its reducer and communication hook hold this process group) while the group
        # is alive. The step closure of setup() and the trainer form a reference cycle, which the
        # cyclic garbage collector would free at any later time, after the group is destroyed
        # (or in a later run's group); under load that aborted a rank with "terminate called
        # without an active exception" (tests/test_scaleout.py, a stop-and-resume in one process).
        if trainer is not None:
            trainer.__dict__.pop("train_step", None)
            trainer.train_forward = trainer.network
            trainer.dist = None
        trainer = state = None  # noqa: F841  (drop the last references before the collection)
        gc.collect()
        dist.destroy_process_group()


def describe(path) -> dict[str, Any] | None:
    """The ``distributed.json`` of a run folder, if any."""
    p = os.path.join(str(path), "distributed.json")
    if not os.path.exists(p):
        return None
    with open(p) as fh:
        return json.load(fh)
