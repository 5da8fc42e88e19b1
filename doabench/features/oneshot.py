"""One call from audio to SRP-PHAT maps, as handy as ``pyroomacoustics.doa``::

    import doabench
    out = doabench.srp_maps(audio, "nao", fs=16000, resolution=(16, 32))
    out.maps          # (frames, 16, 32) or (batch, frames, 16, 32), normalised (maximum 1)
    out.colatitudes   # (16,) radians from +z (doabench's "elevation"), 0..pi (0..pi/2 planar)
    out.azimuths      # (32,) radians, -pi..pi
    out.directions    # unit vectors of each map's maximum, (..., frames, 3)
    out.times         # (frames,) window centres in seconds

``audio`` is ``(mics, samples)`` or ``(batch, mics, samples)``, numpy or torch; the outputs have a
batch axis exactly when the input has one.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch
from numpy.typing import ArrayLike

from doabench.arrays import MicArray, get_array
from doabench.errors import InputError
from doabench.features.configs import DEFAULT_RESOLUTION
from doabench.features.kinds import DelayMode
from doabench.framing import FrameSpec
from doabench.geometry import grid_angles


@dataclass(frozen=True)
class SrpMaps:
    """What :func:`srp_maps` returns (numpy arrays)."""

    maps: np.ndarray
    colatitudes: np.ndarray
    azimuths: np.ndarray
    directions: np.ndarray
    times: np.ndarray
    planar: bool

    @property
    def elevations(self) -> np.ndarray:
        """Alias of :attr:`colatitudes` (doabench calls the angle from +z "elevation")."""
        return self.colatitudes


def srp_maps(audio: ArrayLike | torch.Tensor, array: MicArray | str, fs: int = 16000,
             resolution: str | Sequence[int] = DEFAULT_RESOLUTION, window: int = 4096,
             hop: int | None = None, mode: DelayMode = "nearest", normalize: bool = True,
             device: str | None = None) -> SrpMaps:
    """SRP-PHAT maps of ``audio`` for ``array`` (a built-in name, a JSON/YAML file or a MicArray).

    ``mode``: ``nearest`` (integer-sample delays, the paper's) or ``exact``; ``normalize``: mean
    removed and divided by the maximum (docs/features.md); ``hop`` defaults to 3/4 of ``window``.
    """
    from doabench.features.transforms import SRPPHAT
    from doabench.features.functional import map_argmax_directions

    mic_array = get_array(array)
    x = torch.as_tensor(np.asarray(audio) if not isinstance(audio, torch.Tensor) else audio)
    if x.ndim not in (2, 3):
        raise InputError(f"audio must be (mics, samples) or (batch, mics, samples), got shape {tuple(x.shape)}")
    batched = x.ndim == 3
    if not batched:
        x = x[None]
    if x.shape[1] != mic_array.n_mics:
        raise InputError(f"audio has {x.shape[1]} channels but array {mic_array.name!r} has {mic_array.n_mics} "
                         "microphones (expected (mics, samples) or (batch, mics, samples))")
    x = x.to(dtype=torch.float32, device=device or "cpu")
    spec = FrameSpec(int(window), hop, int(fs))
    srp = SRPPHAT(mic_array, resolution, spec, mode=mode, normalize=normalize)
    with torch.inference_mode():
        maps = srp(x)
        dirs = map_argmax_directions(maps, planar=srp.planar)
    col, az = grid_angles(*srp.resolution, planar=srp.planar)
    maps_np, dirs_np = maps.cpu().numpy(), dirs.cpu().numpy()
    if not batched:
        maps_np, dirs_np = maps_np[0], dirs_np[0]
    return SrpMaps(maps=maps_np, colatitudes=col, azimuths=az, directions=dirs_np,
                   times=spec.times(maps.shape[1]), planar=srp.planar)
