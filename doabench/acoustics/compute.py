"""Where and how the acoustics compute: the device, chunk sizes, seeded generators, serial sections."""
from __future__ import annotations

import contextlib

import numpy as np
import torch


def resolve_device(device: str | torch.device | None) -> torch.device:
    return torch.device("cpu") if device is None else torch.device(device)


def work_elements(device: torch.device, cpu: int, accelerator: int) -> int:
    """Elements per piece of chunked work on ``device``: ``cpu`` (cache-sized) on the CPU,
    ``accelerator`` (larger, to amortise kernel launches) elsewhere."""
    return cpu if torch.device(device).type == "cpu" else accelerator


def make_generator(seed: int | torch.Generator | None) -> torch.Generator:
    """A CPU generator: ``seed`` as is when it is one, else seeded with ``seed`` (a fresh random
    seed when None).

    On the CPU whatever device simulates: CUDA's generator draws other numbers for the same seed,
    so a task's episode would change with ``--device``; the draws (the diffuse tail's noise, a few
    MB at most) are moved to the device instead."""
    if isinstance(seed, torch.Generator):
        return seed
    if seed is None:
        seed = int(np.random.SeedSequence().generate_state(1, np.uint64)[0] >> 1)
    gen = torch.Generator()
    gen.manual_seed(int(seed))
    return gen


@contextlib.contextmanager
def single_threaded():
    """Run torch ops on the calling thread only, restoring the thread count afterwards.

    For loops of many small ops: each would otherwise be handed to the OpenMP pool (sqrt_ and
    other VML kernels go parallel from 2048 elements), and on an oversubscribed machine the
    hand-offs cost far more than the work (20x slower with 2 threads at a load of 8 on 2 cores).
    Changes torch's process-wide thread count while it runs.
    """
    n = torch.get_num_threads()
    if n == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)
