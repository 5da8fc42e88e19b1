"""Chunk-by-chunk feature extraction, identical to the offline :class:`FeatureExtractor`.

Every feature of a frame depends only on that frame's samples (maps are normalised per map), so
computing the frames a chunk completes, on just the samples those frames cover, gives the
offline result for any chunking. Between calls only the samples of not-yet-complete frames are
kept (at most one window).
"""
from __future__ import annotations

from typing import Any

import numpy as np
import torch
from numpy.typing import ArrayLike

from doabench.errors import InputError
from doabench.framing import FrameSpec
from doabench.features.transforms import FeatureExtractor, prepare_audio, prepare_vad


class FrameStream:
    """Buffers samples for one FrameSpec and releases segments of complete frames (the streaming
    extractor's, and ``doabench track``'s framing of raw ``audio`` observations)."""

    def __init__(self, spec: FrameSpec) -> None:
        self.spec = spec
        self.audio: torch.Tensor | None = None  # (B, M, n) from the next frame's first sample
        self.vad: torch.Tensor | None = None  # (B, n) bool, or None while no VAD was given
        self.skip = 0  # samples still to drop before the next frame starts (hop > window)

    def push(self, x: torch.Tensor, vad: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor] | None:
        """Add ``x (B, M, n)``/``vad (B, n)``; return the segment covering the completed frames."""
        if self.skip:
            drop = min(self.skip, x.shape[-1])
            x, vad, self.skip = x[..., drop:], vad[..., drop:], self.skip - drop
        self.audio = x if self.audio is None else torch.cat([self.audio, x], dim=-1)
        self.vad = vad if self.vad is None else torch.cat([self.vad, vad], dim=-1)
        n = self.spec.n_frames(self.audio.shape[-1])
        if n == 0:
            return None
        end = (n - 1) * self.spec.hop + self.spec.window
        segment = (self.audio[..., :end], self.vad[..., :end])
        advance = n * self.spec.hop
        have = self.audio.shape[-1]
        # Copies, so that the long-gone part of a big chunk is not kept alive by a view.
        self.audio = self.audio[..., advance:].clone()
        self.vad = self.vad[..., advance:].clone()
        self.skip = max(0, advance - have)
        return segment


class StreamingFeatureExtractor:
    """Push audio chunks, get the features of every frame each chunk completes.

    Same constructor as :class:`FeatureExtractor`. ``push(chunk, vad_chunk=None)``: ``chunk``
    ``(n_mics, n)`` or ``(batch, n_mics, n)`` (keep one layout and batch size until
    :meth:`reset`), ``vad_chunk`` ``(n,)``/``(batch, n)`` or None (active). Returns the same dict
    as the offline extractor restricted to the new frames, possibly with zero frames; the
    concatenation over chunks equals the offline result on the whole recording.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:  # FeatureExtractor's
        self.extractor = FeatureExtractor(*args, **kwargs)
        self.reset()

    def reset(self) -> None:
        """Forget buffered audio; the next push starts a new recording."""
        ex = self.extractor
        self._main = FrameStream(ex.frame_spec)
        self._spec = FrameStream(ex.spectrogram_frame_spec) if ex.separate_spectrogram_grid else None
        self._layout: tuple[int, bool] | None = None
        self.samples_seen = 0

    @property
    def buffered_samples(self) -> int:
        """Samples per channel held for the next frame of the main grid (from its first sample):
        what a push keeps between calls, less than a window once any frame was emitted."""
        audio = self._main.audio
        return 0 if audio is None else int(audio.shape[-1])

    def push(
        self, chunk: np.ndarray | torch.Tensor, vad_chunk: ArrayLike | torch.Tensor | None = None
    ) -> dict[str, torch.Tensor]:
        ex = self.extractor
        x, batched = prepare_audio(chunk, ex.array.n_mics)
        layout = (x.shape[0], batched)
        if self._layout is not None and layout != self._layout:
            raise InputError(
                f"chunk batch layout {layout} differs from the earlier chunks' {self._layout}; call reset() first"
            )
        self._layout = layout
        vad = prepare_vad(vad_chunk, x.shape[0], x.shape[-1], batched, x.device)
        if vad is None:
            vad = torch.ones((x.shape[0], x.shape[-1]), dtype=torch.bool, device=x.device)
        self.samples_seen += x.shape[-1]
        out = ex.empty(x.shape[0], x.device)
        seg = self._main.push(x, vad)
        if seg is not None:
            out.update(ex.compute(*seg, main=True, separate=False))
        if self._spec is not None:
            seg = self._spec.push(x, vad)
            if seg is not None:
                out.update(ex.compute(*seg, main=False, separate=True))
        return out if batched else {k: v[0] for k, v in out.items()}
