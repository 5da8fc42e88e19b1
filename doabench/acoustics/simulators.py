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

from importlib import metadata
from typing import Callable

import torch

from doabench.acoustics import rir as engine
from doabench.acoustics.backends.base import Simulator
from doabench.errors import ConfigError, DependencyError, NotFoundError

ENTRY_POINT_GROUP = "doabench.simulators"
_BACKENDS: dict[str, Callable[[torch.device], Simulator]] = {}

__all__ = ["ENTRY_POINT_GROUP", "Simulator", "get_simulator", "register_simulator", "simulator_names"]


def register_simulator(name: str, factory: Callable[[torch.device], Simulator]) -> None:
    """Register a backend: ``factory(device)`` returns a :class:`Simulator`."""
    _BACKENDS[str(name).lower()] = factory


def _declared() -> dict[str, str]:
    return {ep.name: ep.value for ep in metadata.entry_points(group=ENTRY_POINT_GROUP)}


def _load(name: str) -> None:
    target = _declared().get(name)
    if target is None:
        return
    module_name, _, attr = target.partition(":")
    module = __import__(module_name, fromlist=[attr])
    _BACKENDS.setdefault(name, getattr(module, attr))


def simulator_names() -> list[str]:
    """Every backend registered or declared (none is imported): the default first, then by name."""
    return sorted({*_declared(), *_BACKENDS}, key=lambda n: (n != "builtin", n))


def get_simulator(name: str = "builtin", device: str | torch.device | None = None) -> Simulator:
    """A backend by name: ``builtin`` (default; torch on ``device``, CPU when None),
    ``pyroomacoustics``, ``gpurir`` (DependencyError when gpuRIR is not importable) or a plug-in's."""
    key = str(name).lower()
    if key not in _BACKENDS:
        _load(key)
    if key not in _BACKENDS:
        raise NotFoundError(f"unknown simulator {name!r}: use one of {', '.join(simulator_names())}")
    try:
        dev = engine.resolve_device(device)
    except (RuntimeError, TypeError):
        raise ConfigError(f"unknown torch device {device!r}") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise DependencyError(f"device {device!r} requested but torch has no CUDA device here")
    return _BACKENDS[key](dev)
