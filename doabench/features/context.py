"""The shared STFT context of one extractor pass: each stage computed once, for every kind that reads it.

A :class:`~doabench.features.kinds.FeatureKind` computes itself from an :class:`STFTContext`
(``kind.compute(stft)``): the srp kind reads ``stft.maps``, gcc ``stft.gcc``, a plug-in kind
whatever it needs (the framed samples, the spectra, their PHAT whitening, ...). The stages are
lazy and cached, so a pass asking for srp, srp_max and gcc takes one STFT, one whitening, one GCC
and one set of maps, and a kind nobody asked for costs nothing.

Stages, for ``audio (batch, n_mics, samples)`` on ``frame_spec`` (``frames = 1 + (samples -
window) // hop``):

* ``frames``: ``(batch, frames, n_mics, window)`` the samples of each frame (a strided view);
* ``spectra``: ``(batch, frames, n_mics, window // 2 + 1)`` complex, Hann-windowed rfft;
* ``whitened``: the spectra PHAT-whitened (``functional.phat``);
* ``gcc``: ``(batch, frames, n_pairs, 2 * max_lag + 1)`` GCC-PHAT (needs the ``gcc`` stage);
* ``maps``: ``(batch, frames, n_theta, n_phi)`` normalised SRP-PHAT maps (needs ``srp``);
* ``map_maxima``: ``(batch, frames, 2)`` where each map peaks, as fractions of the grid span;
* ``spectrogram``: ``(batch, frames, 2 * n_mics, window // 2)`` magnitude and phase channels.
* ``spectrogram_ipd``: the same shape, the phases relative to the first microphone's.

Nothing here is masked: the extractor zeroes the silent frames of what each kind returns.
"""
from __future__ import annotations

from functools import cached_property
from typing import Any

import torch

from doabench.errors import ConfigError
from doabench.features import functional as F
from doabench.framing import FrameSpec, frame_signal


class STFTContext:
    """The stages of one batch of recordings on one frame grid (see the module docstring).

    ``audio``: ``(batch, n_mics, samples)`` float32; ``vad``: the frames' VAD ``(batch, frames)``
    bool (read-only context for a kind; the extractor applies it); ``array``: the MicArray;
    ``gcc_transform``/``srp_transform``: the extractor's :class:`~doabench.features.GCCPHAT` and
    :class:`~doabench.features.SRPPHAT` (their tables), None when no requested kind declared the
    stage.
    """

    def __init__(self, audio: torch.Tensor, vad: torch.Tensor, frame_spec: FrameSpec, array: Any,
                 gcc_transform: Any = None, srp_transform: Any = None) -> None:
        self.audio = audio
        self.vad = vad
        self.frame_spec = frame_spec
        self.array = array
        self._gcc = gcc_transform
        self._srp = srp_transform

    def _needs(self, transform: Any, stage: str) -> Any:
        if transform is None:
            raise ConfigError(f"a feature kind read the {stage!r} stage without declaring it in its stages")
        return transform

    @cached_property
    def frames(self) -> torch.Tensor:
        """``(batch, frames, n_mics, window)``: each frame's samples (a view of ``audio``)."""
        return frame_signal(self.audio, self.frame_spec.window, self.frame_spec.hop).transpose(1, 2)

    @cached_property
    def spectra(self) -> torch.Tensor:
        """``(batch, frames, n_mics, window // 2 + 1)`` complex64 spectra (periodic Hann window)."""
        return F.stft_frames(self.audio, self.frame_spec.window, self.frame_spec.hop)

    @cached_property
    def whitened(self) -> torch.Tensor:
        """The spectra PHAT-whitened, same shape (zero bins stay zero)."""
        return F.phat(self.spectra)

    @cached_property
    def gcc(self) -> torch.Tensor:
        """``(batch, frames, n_pairs, 2 * max_lag + 1)`` GCC-PHAT of the array's pairs."""
        gcc: torch.Tensor = self._needs(self._gcc, "gcc").from_phat(self.whitened)
        return gcc

    @cached_property
    def maps(self) -> torch.Tensor:
        """``(batch, frames, n_theta, n_phi)`` SRP-PHAT maps, each minus its mean over its maximum."""
        srp = self._needs(self._srp, "srp")
        # the paper's nearest delays read the GCC (shared with a gcc kind); exact delays do not
        return F.normalize_maps(srp.raw_from_phat(self.whitened, self.gcc if srp.mode == "nearest" else None))

    @cached_property
    def map_maxima(self) -> torch.Tensor:
        """``(batch, frames, 2)``: each map's maximum, elevation row / (rows - 1) and (azimuth + pi) / 2 pi."""
        return F.map_maxima(self.maps, self._needs(self._srp, "srp").planar)

    @cached_property
    def spectrogram(self) -> torch.Tensor:
        """``(batch, frames, 2 * n_mics, window // 2)``: magnitudes over their maximum, then phase / pi."""
        return F.spectrogram_features(self.spectra)

    @cached_property
    def spectrogram_ipd(self) -> torch.Tensor:
        """``(batch, frames, 2 * n_mics, window // 2)``: magnitudes over their maximum, then each mic's
        phase minus the first mic's, / pi (the interchannel phase differences)."""
        return F.spectrogram_features(self.spectra, phase="relative")
