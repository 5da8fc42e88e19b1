"""The simulator interface and what every backend shares: geometry and signal validation, the
single-threaded CPU policy, :class:`TorchBackend` (``rirs`` and ``simulate`` from a backend's RIR
parts) and the free-field :func:`direct_path`.

A backend subclasses :class:`TorchBackend` and implements ``rirs_parts`` (early parts plus a
shared tail: the fast path) or ``rirs_tensor`` (complete RIRs), sets ``name`` and ``versions()``,
and is registered by name (:mod:`doabench.acoustics.simulators`).
"""
from __future__ import annotations

import contextlib
from typing import Protocol, runtime_checkable

import numpy as np
import torch

from doabench.acoustics import compute
from doabench.acoustics import rir as engine
from doabench.acoustics import rir_model
from doabench.acoustics.convolution import convolve_parts, convolve_trajectory, trajectory_fft_size
from doabench.acoustics.room import Room, check_inside
from doabench.errors import ConfigError, InputError

_MIN_SOURCE_MIC_DISTANCE = 1e-3  # metres; 1 / (4 pi r) blows up at the microphone


@runtime_checkable
class Simulator(Protocol):
    """What every backend provides. Positions are room coordinates in metres."""

    name: str

    def versions(self) -> dict[str, str]:
        """Backend, library versions and pinned settings, for provenance."""

    def rirs(
        self, room: Room, sources: np.ndarray, mics: np.ndarray, fs: int, *, seed=None
    ) -> np.ndarray:
        """RIRs ``(S, M, n_taps)`` float32 from ``sources`` ``(S, 3)`` to ``mics`` ``(M, 3)``."""

    def simulate(
        self, room: Room, sources: np.ndarray, mics: np.ndarray, signal: np.ndarray, fs: int, *, seed=None
    ) -> np.ndarray:
        """Microphone signals ``(M, L)`` float32 of ``signal`` ``(L,)`` moving along ``sources``
        ``(S, 3)`` (S == 1: static); ``mics`` ``(M, 3)``, or ``(S, M, 3)`` for an array that moves
        with the trajectory's segments."""


def _check_fs(fs) -> int:
    if isinstance(fs, bool) or not isinstance(fs, (int, np.integer)) or fs <= 0:
        raise ConfigError(f"sample rate must be a positive integer number of Hz, got {fs!r}")
    return int(fs)


def _points(room: Room | None, points, what: str) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim == 1 and p.shape == (3,):
        p = p[None]
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] == 0:
        raise ConfigError(f"{what} positions must have shape (N, 3) with N >= 1, got {np.shape(points)}")
    if room is None:
        if not np.all(np.isfinite(p)):
            i = int(np.argmax(~np.all(np.isfinite(p), axis=1)))
            raise ConfigError(f"{what} {i + 1} is not finite")
        return p
    return check_inside(room, p, what)


def prepare_geometry(room: Room | None, sources, mics, fs) -> tuple[np.ndarray, np.ndarray, int]:
    """Validate and return ``sources (S, 3)``, ``mics`` float64 and ``fs``.

    ``mics`` is ``(M, 3)`` (a static array) or ``(S, M, 3)``: the microphones that hear trajectory
    point ``s`` (a moving array; a single source point is then repeated to ``S`` points)."""
    if room is not None and not isinstance(room, Room):
        raise ConfigError(f"room must be a doabench.acoustics.room.Room, got {type(room).__name__}")
    fs = _check_fs(fs)
    src = _points(room, sources, "source point")
    raw = np.asarray(mics, dtype=np.float64)
    if raw.ndim == 3:  # a moving array
        if raw.shape[2] != 3 or raw.shape[1] == 0 or (len(src) != 1 and raw.shape[0] != len(src)):
            raise ConfigError(f"per-point microphone positions must have shape (S, M, 3) with S = {len(src)} "
                              f"source points, got {raw.shape}")
        mic = _points(room, raw.reshape(-1, 3), "array microphone").reshape(raw.shape)
        if len(src) == 1:
            src = np.repeat(src, raw.shape[0], axis=0)
        d = np.linalg.norm(src[:, None] - mic, axis=-1)
        if d.min() < _MIN_SOURCE_MIC_DISTANCE:
            i, j = np.unravel_index(int(np.argmin(d)), d.shape)
            raise ConfigError(f"source point {i + 1} is at array microphone {j + 1} (closer than 1 mm)")
        return src, mic, fs
    mic = _points(room, mics, "array microphone")
    d = np.linalg.norm(src[:, None] - mic[None], axis=-1)
    if d.min() < _MIN_SOURCE_MIC_DISTANCE:
        i, j = np.unravel_index(int(np.argmin(d)), d.shape)
        raise ConfigError(f"source point {i + 1} is at array microphone {j + 1} (closer than 1 mm)")
    return src, mic, fs


def _signal(signal) -> np.ndarray:
    x = np.asarray(signal)
    if x.ndim != 1 or x.size == 0:
        raise InputError(f"source signal must be 1-D and non-empty, got shape {x.shape}")
    if not np.issubdtype(x.dtype, np.number) or not np.all(np.isfinite(x)):
        raise InputError("source signal contains NaN, infinite or non-numeric values")
    return x.astype(np.float32, copy=False)


def direct_path(
    room: Room | None,
    sources: np.ndarray,
    mics: np.ndarray,
    signal: np.ndarray,
    fs: int,
    *,
    device: str | torch.device | None = None,
) -> np.ndarray:
    """Free-field direct-path signals ``(M, L)`` float32: amplitude ``1 / (4 pi r)``, delay
    ``r / c`` by the builtin engine's windowed sinc, same segmenting and overlap-add as
    :meth:`Simulator.simulate`. ``room`` (optional) only validates the positions. Used to set an
    SNR relative to the direct-path power without a second simulation."""
    src, mic, fs = prepare_geometry(room, sources, mics, fs)
    x = _signal(signal)
    dev = compute.resolve_device(device)
    with _threads(dev):
        h = engine.direct_rirs(torch.tensor(src, device=dev), torch.tensor(mic, device=dev), fs)
        return convolve_trajectory(h, torch.as_tensor(x, device=dev)).cpu().numpy()


def _threads(device: torch.device):
    """Single-threaded torch on CPU for the duration of a simulation.

    One trajectory is many medium-sized ops: two threads gained little on an idle 2-core machine,
    and on a loaded one the thread-pool hand-offs made it 5-20x slower. To use more cores,
    simulate several trajectories in parallel processes (e.g. data-loader workers).
    """
    return compute.single_threaded() if device.type == "cpu" else contextlib.nullcontext()


class TorchBackend:
    """Shared ``rirs``/``simulate`` plumbing. Subclasses implement ``rirs_parts`` (early parts
    plus a shared tail, :class:`~doabench.acoustics.rir_model.RirParts`; the fast path) or only
    ``rirs_tensor`` (complete RIRs, convolved per trajectory point)."""

    name = "?"
    device: torch.device

    def rirs_parts(
        self, room: Room, sources: np.ndarray, mics: np.ndarray, fs: int, generator, width: int | None = None
    ) -> rir_model.RirParts | None:
        return None

    def rirs_tensor(self, room: Room, sources: np.ndarray, mics: np.ndarray, fs: int, generator) -> torch.Tensor:
        parts = self.rirs_parts(room, sources, mics, fs, generator)
        if parts is None:
            raise NotImplementedError
        return parts.full()

    def rirs(self, room: Room, sources, mics, fs: int, *, seed=None) -> np.ndarray:
        """RIRs ``(S, M, n_taps)`` float32, ``n_taps = round(Tmax fs)`` (direct path only when
        T60 = 0). ``seed`` (int or torch.Generator) fixes the diffuse-tail noise."""
        src, mic, fs = prepare_geometry(room, sources, mics, fs)
        gen = compute.make_generator(seed)
        with _threads(self.device):
            return self.rirs_tensor(room, src, mic, fs, gen).cpu().numpy()

    def simulate(self, room: Room, sources, mics, signal, fs: int, *, seed=None) -> np.ndarray:
        """Signals ``(M, L)`` float32 of ``signal`` ``(L,)`` moving along ``sources`` ``(S, 3)``;
        equals :func:`convolve_trajectory` of :meth:`rirs` with the same seed (to float32
        rounding where the backend has a shared tail)."""
        src, mic, fs = prepare_geometry(room, sources, mics, fs)
        x = _signal(signal)
        gen = compute.make_generator(seed)
        xt = torch.as_tensor(x, device=self.device)
        with _threads(self.device):
            layout, _ = rir_model.plan(room, torch.tensor(src), torch.tensor(mic), fs)
            nfft = trajectory_fft_size(len(x), len(src), layout.n_early)
            parts = self.rirs_parts(room, src, mic, fs, gen, width=nfft)  # zero-padded: no copy in the FFT
            if parts is not None:
                return convolve_parts(parts, xt).cpu().numpy()
            h = self.rirs_tensor(room, src, mic, fs, gen)
            return convolve_trajectory(h, xt).cpu().numpy()
