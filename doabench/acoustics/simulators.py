"""Room simulators by name: one interface (:class:`~doabench.acoustics.backends.base.Simulator`),
backends as plugins.

doabench's own backends are declared in its ``pyproject.toml`` under the ``doabench.simulators``
entry-point group, exactly as a third-party package declares one (``name =
"package.module:Class"``; the class is called with a torch device):

* ``builtin`` (default): doabench's torch image-source engine (:mod:`doabench.acoustics.rir`), CPU
  or CUDA (:mod:`doabench.acoustics.backends.builtin`);
* ``pyroomacoustics``: the same model through ``pyroomacoustics.ShoeBox``, the trusted reference
  (:mod:`doabench.acoustics.backends.pra`);
* ``gpurir``: gpuRIR, the library the Cross3D paper used, when it is importable
  (:mod:`doabench.acoustics.backends.gpurir`).

:func:`register_simulator` adds one at run time. Every backend returns RIRs ``(S, M, n_taps)`` and
simulates a moving source with the shared convolution of :mod:`doabench.acoustics.convolution`.
"""
from __future__ import annotations

from typing import Callable

import torch

from doabench.acoustics import compute
from doabench.acoustics.backends.base import Simulator
from doabench.errors import ConfigError, DependencyError
from doabench.plugins import Registry

ENTRY_POINT_GROUP = "doabench.simulators"

#: Every backend, doabench's own declared in its pyproject.toml as a plug-in's (:mod:`doabench.plugins`).
SIMULATORS: Registry[Callable[[torch.device], Simulator]] = Registry("simulator", ENTRY_POINT_GROUP, declares_own=True)

__all__ = ["ENTRY_POINT_GROUP", "SIMULATORS", "Simulator", "get_simulator", "register_simulator", "simulator_names"]


def register_simulator(name: str, factory: Callable[[torch.device], Simulator]) -> None:
    """Register a backend: ``factory(device)`` returns a :class:`Simulator`. Another factory under
    a taken name is a ConfigError."""
    SIMULATORS.register(name, factory)


def simulator_names() -> list[str]:
    """Every backend registered or declared (none is imported): the default first, then by name."""
    return sorted(SIMULATORS.names(), key=lambda n: (n != "builtin", n))


def get_simulator(name: str = "builtin", device: str | torch.device | None = None) -> Simulator:
    """A backend by name: ``builtin`` (default; torch on ``device``, CPU when None),
    ``pyroomacoustics``, ``gpurir`` (DependencyError when gpuRIR is not importable) or a plug-in's."""
    factory = SIMULATORS.get(str(name))
    try:
        dev = compute.resolve_device(device)
    except (RuntimeError, TypeError):
        raise ConfigError(f"unknown torch device {device!r}") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise DependencyError(f"device {device!r} requested but torch has no CUDA device here")
    return factory(dev)
