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
    * ``sample_valid``: ``(n_samples,)`` bool, False where the truth is not valid (LOCATA's
      ``valid_flag = 0``): such frames are left out of scoring. None: all valid.
    * ``input_vad``: the voice activity the features are masked with (silent frames' features are
      zero), when it differs from ``sample_vad`` (LOCATA: voice activity regardless of validity,
      so invalid frames keep their maps in the network's input). None: ``sample_vad``.
    """

    audio: np.ndarray
    fs: int
    sample_vad: np.ndarray
    sample_directions: np.ndarray
    metadata: dict[str, Any] = field(default_factory=dict)
    array: MicArray | None = None
    sample_valid: np.ndarray | None = None
    input_vad: np.ndarray | None = None

    @property
    def feature_vad(self) -> np.ndarray:
        """The per-sample VAD the features are masked with."""
        return self.sample_vad if self.input_vad is None else self.input_vad

    @property
    def n_samples(self) -> int:
        return int(self.audio.shape[-1])

    @property
    def n_mics(self) -> int:
        return int(self.audio.shape[0])

    def frame_truth(self, frame_spec: FrameSpec) -> dict[str, np.ndarray]:
        """Per-frame truth: ``directions (T, 3)``, ``elevation``/``azimuth`` ``(T,)`` in radians,
        ``vad (T,)`` bool (active when more than 2/3 of the window's samples are active) and
        ``times (T,)`` in seconds (window centres), and ``valid (T,)`` bool when the episode has
        ``sample_valid``."""
        dirs = frame_mean_directions(self.sample_directions, frame_spec.window, frame_spec.hop)
        el, az = unit_to_angles(dirs)
        vad = frame_vad(self.sample_vad, frame_spec.window, frame_spec.hop)
        out = {
            "directions": dirs,
            "elevation": el,
            "azimuth": az,
            "vad": np.asarray(vad, dtype=bool),
            "times": frame_spec.times(len(dirs)),
        }
        if self.sample_valid is not None:  # a frame is scored when more than 2/3 of its samples are valid
            out["valid"] = np.asarray(frame_vad(self.sample_valid, frame_spec.window, frame_spec.hop), dtype=bool)
        return out
