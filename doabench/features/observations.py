"""Per-frame observations of one recording, as environments and ``doabench track`` hand them out.

Besides the :class:`~doabench.features.FeatureExtractor` kinds, the ``audio`` kind gives each
frame's raw samples ``(n_mics, window)``, for trackers that do their own analysis (e.g. the
pyroomacoustics subspace methods).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from doabench.framing import FrameSpec, frame_signal


def recording_features(extractor, audio: np.ndarray, sample_vad: np.ndarray | None, kinds: Sequence[str],
                       frame_spec: FrameSpec, device: str | None = None) -> dict[str, np.ndarray]:
    """``audio (n_mics, samples)`` -> ``{kind: (T, ...)}`` numpy arrays plus ``vad (T,)`` int64.

    ``extractor`` computes every kind but ``audio``; ``sample_vad`` None means all active.
    """
    x = torch.as_tensor(np.ascontiguousarray(audio), dtype=torch.float32, device=device)[None]
    vad = None if sample_vad is None else torch.as_tensor(np.asarray(sample_vad, bool), device=device)[None]
    with torch.inference_mode():
        feats = {k: v[0].detach().cpu().numpy() for k, v in extractor(x, vad).items()}
    if "audio" in kinds:
        # (M, T, K) strided view -> (T, M, K); copied per observation by the caller
        feats["audio"] = np.moveaxis(frame_signal(np.asarray(audio, np.float32), frame_spec.window, frame_spec.hop), 0, 1)
    feats["vad"] = np.asarray(feats["vad"]).astype(np.int64)
    return feats


def extractor_kinds(kinds: Sequence[str]) -> tuple[str, ...]:
    """The kinds a FeatureExtractor computes (``audio`` is framed directly); never empty."""
    out = tuple(k for k in kinds if k != "audio")
    return out or ("srp_max",)
