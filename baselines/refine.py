"""Refining a learned tracker's direction on a finer SRP-PHAT map (the ``refine`` option).

Cross3D regresses a direction from coarse maps (16x32: a cell is 11.25 deg wide); a classical
tracker on the paper's finer maps is more precise wherever the direct path is the strongest peak,
and worse wherever a reflection or noise outshouts it. Refinement keeps the network's choice of
*where* and takes the fine map's *exactly where*: on every voice-active frame, the direction is
replaced by the maximum of a finer SRP-PHAT map (e.g. 64x128, the finest of the paper's Table II)
among the map cells within ``radius`` degrees of the network's direction. Silent frames keep the
network's direction (their maps hold no talker); the hold rule runs after refinement, so it
holds a refined direction. It adds no lag: the map is that of the same frame.

``refine_speed`` gates it by the network's own speed: a frame is refined only where the network's
direction turned faster than that many degrees per second over the last :data:`SPEED_FRAMES`
frames (0, the default: every voice-active frame). Refinement gains on fast talkers, whom the
network's output trails, and costs on still ones, where the network is the more precise.

The fine map is computed from the frame's audio (the ``audio`` observation) with
:class:`doabench.SRPPHAT` on the nearest-sample delays (the maps' argmax is all that is used, so
their normalisation does not matter). What it gave is in docs/results.md ("Refined on the paper's
finest maps").
"""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np

import doabench
from doabench.errors import ConfigError

from doabench.trackers import parse_resolution, resolution_text

from .hold import OFF_VALUES


def parse_refine(value: str | None) -> tuple[int, int] | None:
    """The ``refine`` option: None for ``off``, else the fine map's ``(n_theta, n_phi)``."""
    if value is None or str(value).strip().lower() in (*OFF_VALUES, ""):
        return None
    try:
        return parse_resolution(str(value).strip())
    except ConfigError as exc:
        raise ConfigError(f"refine must be off or a map resolution such as 64x128: {exc}") from None


def _number(value: str | float) -> float:
    """``value`` as a float, NaN where it is none (so that one range check refuses both)."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


#: frames over which the network's speed is measured for ``refine_speed`` (causal: this frame's
#: direction against the one this many frames before; an episode's first frames against its first)
SPEED_FRAMES = 2


def parse_speed(value: str | float) -> float:
    """The ``refine_speed`` option: degrees per second, at least 0 (0: refine every voice-active frame)."""
    speed = _number(value)
    if not speed >= 0 or math.isinf(speed):
        raise ConfigError(f"refine_speed must be degrees per second >= 0 (0: every voice-active frame), got {value!r}")
    return speed


def parse_radius(value: str | float, network_resolution: tuple[int, int], planar: bool = False) -> float:
    """The ``refine_radius`` option in degrees: ``auto`` is one cell of the network's own map (its
    larger grid step: 12 deg at 16x32, the elevation step 180 / 15), else a number in (0, 90]."""
    if str(value).strip().lower() == "auto":
        n_theta, n_phi = network_resolution
        return max((90.0 if planar else 180.0) / (n_theta - 1), 360.0 / n_phi)
    radius = _number(value)
    if not 0 < radius <= 90:
        raise ConfigError(f"refine_radius must be auto or degrees in (0, 90], got {value!r}")
    return radius


class MapRefiner:
    """Moves directions to the maximum of a finer SRP-PHAT map within ``radius_deg`` of them.

    ``refiner(directions, audio, active)``: ``directions`` ``(frames, 3)`` unit vectors,
    ``audio`` ``(frames, n_mics, window)`` (the ``audio`` observation), ``active`` ``(frames,)``
    bool (voice-active frames, the ``vad`` observation) -> ``(frames, 3)``: refined where active.

    With ``min_speed_deg_s`` > 0 only the frames where the network's direction turns faster than
    that are refined; the speed is measured on the directions the refiner was given, which
    continue those of its earlier calls (one refiner per episode: a whole episode at once and the
    same frames one call each give the same result).
    """

    def __init__(self, array: doabench.MicArray, resolution: tuple[int, int], frame_spec: doabench.FrameSpec,
                 radius_deg: float, min_speed_deg_s: float = 0.0) -> None:
        import torch

        self.resolution = tuple(resolution)
        self.radius_deg = float(radius_deg)
        self.min_speed_deg_s = float(min_speed_deg_s)
        self._hop_s = frame_spec.hop / frame_spec.fs
        self._recent = np.zeros((0, 3))  # the last SPEED_FRAMES network directions of earlier calls
        # One frame per call: the audio observation is one window, so hop = window gives one frame.
        one_frame = doabench.FrameSpec(frame_spec.window, frame_spec.window, frame_spec.fs)
        self._srp = doabench.SRPPHAT(array, self.resolution, one_frame, normalize=False)
        self._cells = torch.from_numpy(self._srp.grid_directions.reshape(-1, 3))  # (G, 3) float64
        self._cos_radius = math.cos(math.radians(self.radius_deg))

    def __repr__(self) -> str:
        gate = f", above {self.min_speed_deg_s:g} deg/s" if self.min_speed_deg_s > 0 else ""
        return f"MapRefiner({resolution_text(self.resolution)}, radius {self.radius_deg:g} deg{gate})"

    def fast(self, directions: np.ndarray) -> np.ndarray:
        """``(frames,)`` bool: where the network's ``(frames, 3)`` directions turn faster than
        ``min_speed_deg_s`` (each against the one :data:`SPEED_FRAMES` frames before, across calls)."""
        before = self._recent if len(self._recent) else np.repeat(directions[:1], SPEED_FRAMES, axis=0)
        seen = np.concatenate([before, directions])
        self._recent = seen[-SPEED_FRAMES:]
        cos = np.clip(np.sum(seen[SPEED_FRAMES:] * seen[:-SPEED_FRAMES], axis=1), -1.0, 1.0)
        return np.degrees(np.arccos(cos)) / (SPEED_FRAMES * self._hop_s) > self.min_speed_deg_s

    def __call__(self, directions: np.ndarray, audio: np.ndarray, active: np.ndarray) -> np.ndarray:
        import torch

        directions = np.asarray(directions, dtype=np.float64)
        active = np.asarray(active, dtype=bool)
        if self.min_speed_deg_s > 0 and len(directions):
            active = active & self.fast(directions)
        out = directions.copy()
        if not active.any():
            return out
        frames = torch.as_tensor(np.asarray(audio, dtype=np.float32)[active])  # (A, n_mics, window)
        with torch.inference_mode():
            maps = self._srp(frames)[:, 0].reshape(len(frames), -1).double()  # (A, G)
            near = torch.from_numpy(directions[active]) @ self._cells.T >= self._cos_radius  # (A, G)
            best = maps.masked_fill(~near, -math.inf).argmax(dim=1)  # (A,)
            found = near.any(dim=1)
        refined = out[active]
        refined[found.numpy()] = self._cells[best[found]].numpy()
        out[active] = refined
        return out

    def episode(self, directions: np.ndarray, observations: Mapping[str, np.ndarray]) -> np.ndarray:
        """Refine ``(frames, 3)`` directions with the episode's (or one frame's, batched) ``audio`` and ``vad``."""
        return self(directions, observations["audio"], observations.get("vad", np.ones(len(directions), bool)))
