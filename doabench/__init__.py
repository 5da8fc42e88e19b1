"""doabench: benchmark suite and dataset generator for single-source DOA estimation and tracking.

Public API::

    import doabench
    doabench.Tracker, doabench.register_tracker, doabench.make_tracker   # trackers
    doabench.register_task, doabench.get_task_spec, doabench.available_tasks  # tasks
    env = gymnasium.make("doabench/sim-demo-v2", features=("srp",), resolution=(16, 32))
    doabench.run(tracker="srp-max", task="sim-demo")                   # scored results dict
    doabench.srp_maps(audio, "nao")    # SRP-PHAT maps + grid angles + argmax directions in one call
    doabench.SRPPHAT("nao", (64, 128))  # the same maps as a transform built once (tables kept)
    doabench.hold_in_silences(directions, vad, hold)   # the learned trackers' hold rule in silences
    doabench.SilenceHold(hold).step(direction, voiced)  # the same rule, frame by frame
    doabench.NO_SOURCE   # three NaNs: what step() returns (a row of track()) for a frame with no source

What users implement or receive: ``Tracker`` (subclass it) and the ``ResetContext`` its
``reset(array, **context)`` gets; ``TaskSpec`` (a task's parsed TOML); ``EpisodeSource`` (the
protocol a task kind's episode source implements, registered with ``register_task_kind``);
``TrainableTracker`` (what ``doabench train`` needs from a learned tracker; it needs torch, which
is imported only when the name is first used); ``ObservationPlan`` (a recording's per-frame
observations, names and spaces, as every task computes them; also loaded on first use);
``SRPPHAT`` (the SRP-PHAT transform of ``srp_maps``, built once and called per frame or episode;
loaded on first use).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

from doabench._version import __version__

from doabench.arrays import MicArray, get_array, load_array_file
from doabench.envs.registry import available_tasks, get_task_spec, register_task
from doabench.envs.sources import EpisodeSource, register_task_kind
from doabench.envs.spec import TaskSpec
from doabench.episode import Episode
from doabench.errors import DoabenchError
from doabench.features.configs import FramesConfig, KindConfig, MapConfig
from doabench.features.spec import ConfiguredKind, ObservationSpec
from doabench.framing import FrameSpec
from doabench.geometry import NO_SOURCE
from doabench.trackers import SilenceHold, Tracker, available_trackers, hold_in_silences, make_tracker, register_tracker
from doabench.trackers.base import ResetContext

if TYPE_CHECKING:
    from doabench.training.protocol import TrainableTracker


def _one_torch_thread_after_fork() -> None:
    """In a forked child (``gymnasium.make_vec(..., vectorization_mode="async")`` forks on Linux),
    torch's intra-op thread pool inherited from a parent that already ran torch work is unusable
    and the first parallel op hangs; one thread per child avoids the pool (what torch's own
    DataLoader workers do). Processes started with ``spawn`` are unaffected."""
    import sys

    torch = sys.modules.get("torch")
    if torch is not None:
        try:
            torch.set_num_threads(1)
        except Exception:  # never break a fork
            pass


_fork_guard_installed = False


def _install_fork_guard() -> None:
    global _fork_guard_installed
    import os

    if hasattr(os, "register_at_fork") and not _fork_guard_installed:
        os.register_at_fork(after_in_child=_one_torch_thread_after_fork)
        _fork_guard_installed = True


_install_fork_guard()


def srp_maps(audio, array, **kwargs):
    """SRP-PHAT maps of ``(mics, samples)`` or ``(batch, mics, samples)`` audio with the grid's
    colatitudes and azimuths; see :func:`doabench.features.oneshot.srp_maps`."""
    from doabench.features.oneshot import srp_maps as _srp_maps

    return _srp_maps(audio, array, **kwargs)


def run(tracker, task, **kwargs):
    """Run a tracker (id or instance) on a task; see :func:`doabench.runner.run_task`."""
    from doabench.runner import run_task

    return run_task(tracker, task, **kwargs)


def __getattr__(name: str) -> Any:
    """``TrainableTracker``, ``single_threaded``, ``ObservationPlan``, ``SRPPHAT``, ``atomic_path`` and
    ``upgrade_weights_metadata`` on first use: ``import
    doabench`` stays light (the first two's and SRPPHAT's modules import torch; ObservationPlan's
    imports gymnasium and builds on torch)."""
    if name == "TrainableTracker":
        from doabench.training.protocol import TrainableTracker

        globals()[name] = TrainableTracker
        return TrainableTracker
    if name == "single_threaded":
        from doabench.acoustics.compute import single_threaded

        globals()[name] = single_threaded
        return single_threaded
    if name == "ObservationPlan":
        from doabench.features.plan import ObservationPlan

        globals()[name] = ObservationPlan
        return ObservationPlan
    if name == "SRPPHAT":  # a transform kept across frames (srp_maps builds one per call)
        from doabench.features.transforms import SRPPHAT

        globals()[name] = SRPPHAT
        return SRPPHAT
    if name == "upgrade_weights_metadata":  # weights files of an older format, read as the current one
        from doabench.results.upgrade import upgrade_weights_metadata

        globals()[name] = upgrade_weights_metadata
        return upgrade_weights_metadata
    if name == "atomic_path":  # the output rule (docs/guarantees.md), for plug-ins that write files
        from doabench.files import atomic_path

        globals()[name] = atomic_path
        return atomic_path
    raise AttributeError(f"module 'doabench' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | {"TrainableTracker", "ObservationPlan", "SRPPHAT", "atomic_path", "single_threaded",
                                    "upgrade_weights_metadata"})


available_tasks()  # registers every task with Gymnasium at import time

__all__ = [
    "ConfiguredKind", "DoabenchError", "Episode", "EpisodeSource", "FrameSpec", "FramesConfig", "KindConfig", "MapConfig",
    "MicArray", "NO_SOURCE", "ObservationPlan", "ObservationSpec",
    "ResetContext", "SRPPHAT", "SilenceHold",
    "TaskSpec", "Tracker", "TrainableTracker", "atomic_path", "available_tasks", "available_trackers", "get_array", "get_task_spec",
    "hold_in_silences", "load_array_file", "make_tracker", "register_task", "register_task_kind", "register_tracker", "run", "single_threaded",
    "srp_maps", "upgrade_weights_metadata", "__version__",
]
