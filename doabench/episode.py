"""An episode: one multichannel recording with its ground truth, simulated or real.

Simulators and corpus readers (LOCATA) produce :class:`Episode` objects; environments turn them
into per-frame features and truth with one :class:`~doabench.framing.FrameSpec`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from doabench.arrays import MicArray
from doabench.framing import FrameSpec, frame_mean_directions, frame_vad
from doabench.geometry import unit_to_angles


@dataclass
class Episode:
    """One recording and its truth, all sample-aligned at ``fs``.

    * ``audio``: ``(n_mics, n_samples)`` float32
    * ``sample_vad``: ``(n_samples,)`` bool, True where the source is active
    * ``sample_directions``: ``(n_samples, 3)`` unit vectors from the array centre to the source,
      in the array frame (float32 or float64)
    * ``metadata``: JSON-serialisable description (scene parameters, recording ids, seed, ...)
    * ``array``: the array geometry this recording was made with, when it differs from the task's
      (e.g. LOCATA's per-recording measured microphone positions); None means the task's array
    """

    audio: np.ndarray
    fs: int
    sample_vad: np.ndarray
    sample_directions: np.ndarray
    metadata: dict[str, Any] = field(default_factory=dict)
    array: MicArray | None = None

    @property
    def n_samples(self) -> int:
        return int(self.audio.shape[-1])

    @property
    def n_mics(self) -> int:
        return int(self.audio.shape[0])

    def frame_truth(self, frame_spec: FrameSpec) -> dict[str, np.ndarray]:
        """Per-frame truth: ``directions (T, 3)``, ``elevation``/``azimuth`` ``(T,)`` in radians,
        ``vad (T,)`` bool (active when more than 2/3 of the window's samples are active) and
        ``times (T,)`` in seconds (window centres)."""
        dirs = frame_mean_directions(self.sample_directions, frame_spec.window, frame_spec.hop)
        el, az = unit_to_angles(dirs)
        vad = frame_vad(self.sample_vad, frame_spec.window, frame_spec.hop)
        return {
            "directions": dirs,
            "elevation": el,
            "azimuth": az,
            "vad": np.asarray(vad, dtype=bool),
            "times": frame_spec.times(len(dirs)),
        }
