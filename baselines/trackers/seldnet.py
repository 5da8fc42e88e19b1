"""``seldnet``: the SELDnet DOA-branch replica (paper V-A), offline."""
from __future__ import annotations

from typing import TYPE_CHECKING

import doabench

from .spectrogram import SpectrogramTracker

if TYPE_CHECKING:
    from torch import nn


@doabench.register_tracker("seldnet")
class SeldnetTracker(SpectrogramTracker):
    """SELDnet DOA-branch replica (paper V-A): offline, bidirectional GRUs, K = 512 windows.

    Frames: 512-sample windows with doabench's 3/4-window hop (384 samples, 24 ms), so its
    estimates are on a finer time grid than the K = 4096 models; the scores compare each tracker
    with the truth of its own frames. Option ``phase``: ``absolute`` (each microphone's phase, the
    paper's), ``relative`` (minus the first microphone's: the ``spectrogram_ipd`` kind) or ``auto``
    (what its weights read).
    """

    model_name = "seldnet"
    causal = False
    observation_spec = doabench.ObservationSpec.of(("spectrogram",), frame_spec=doabench.FrameSpec(window=512))

    def build_model(self) -> nn.Module:
        from ..seldnet import Seldnet

        channels, bins = self._spec_shape()
        return Seldnet(channels, bins)
