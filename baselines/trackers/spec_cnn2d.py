"""``spec-cnn2d``: a causal 2D CNN over magnitude and phase spectrograms, K = 4096 (paper V-A)."""
from __future__ import annotations

from typing import TYPE_CHECKING

import doabench

from .spectrogram import SpectrogramTracker

if TYPE_CHECKING:
    from torch import nn


@doabench.register_tracker("spec-cnn2d")
class SpecCnn2dTracker(SpectrogramTracker):
    """Causal 2D CNN over magnitude and phase spectrograms, K = 4096 (paper V-A).

    Option ``phase``: ``absolute`` (each microphone's phase, the paper's text), ``relative`` (minus
    the first microphone's: the ``spectrogram_ipd`` kind) or ``auto`` (what its weights read).
    """

    model_name = "spec-cnn2d"

    def build_model(self) -> nn.Module:
        from ..cnn2d import SpecCnn2d

        channels, bins = self._spec_shape()
        return SpecCnn2d(channels, bins)
