"""pyroomacoustics' DOA estimators as per-frame trackers: ``music``, ``normmusic``, ``srp-pra``.

Each frame's raw samples (the ``audio`` observation, ``(n_mics, window)``) are split into
512-sample Hann-windowed STFT snapshots (hop 256) and passed to
``pyroomacoustics.doa.algorithms[...]`` with ``dim=3`` on the same equiangular grid as doabench's
SRP maps; the estimate is the grid point it selects. No tracking: silent frames hold the previous
estimate (as ``srp-max``). Options: ``nfft`` (512), ``fmin``/``fmax`` (300/3500 Hz, the speech band
subspace methods are usually run on; ``srp-pra`` defaults to the full band).
"""
from __future__ import annotations

from typing import Any, Mapping, cast

import numpy as np

from doabench.arrays import MicArray
from doabench.features.configs import DEFAULT_RESOLUTION
from doabench.features.spec import ObservationSpec
from doabench.framing import frame_signal
from doabench.geometry import SPEED_OF_SOUND, angles_to_unit, grid_angles, parse_resolution
from doabench.trackers.base import Tracker
from doabench.trackers.registry import register_tracker


class _PyroomacousticsTracker(Tracker):
    observation_spec = ObservationSpec.of(("audio",))  # the recording's frames: it searches its own grid
    causal = True
    algorithm = ""
    default_band: tuple[float, float | None] = (300.0, 3500.0)

    def __init__(self, spec: str | None = None, resolution: str | None = None, nfft: int = 512,
                 fmin: float | None = None, fmax: float | None = None, **options: Any) -> None:
        super().__init__(spec, **options)
        text = resolution or spec
        self._resolution = parse_resolution(text) if text else DEFAULT_RESOLUTION
        self.nfft = int(nfft)
        self.fmin = self.default_band[0] if fmin is None else float(fmin)
        self.fmax = self.default_band[1] if fmax is None else float(fmax)

    @property
    def resolution(self) -> tuple[int, int]:
        """Its own DOA search grid (it reads the recording's frames, not maps)."""
        return self._resolution

    def reset(self, array: MicArray, **context: Any) -> None:
        import pyroomacoustics as pra

        fs = self.frame_spec.fs
        el, az = grid_angles(*self._resolution, planar=bool(array.planar))
        # pyroomacoustics builds its 3-D grid from every (azimuth, colatitude) combination
        self._doa = pra.doa.algorithms[self.algorithm](
            array.positions.T, fs, self.nfft, c=SPEED_OF_SOUND, num_src=1, dim=3, azimuth=az, colatitude=el)
        self._window = np.hanning(self.nfft).astype(np.float32)
        self._band = [self.fmin, self.fmax if self.fmax is not None else fs / 2]
        self._last = np.array([1.0, 0.0, 0.0])

    def step(self, observation: Mapping[str, np.ndarray]) -> np.ndarray:
        if not observation["vad"]:
            return self._last
        snapshots = frame_signal(observation["audio"], self.nfft, self.nfft // 2) * self._window  # (M, S, nfft)
        X = np.fft.rfft(snapshots, axis=-1).transpose(0, 2, 1)  # (M, F, S), the layout pyroomacoustics takes
        self._doa.locate_sources(X, num_src=1, freq_range=self._band)
        direction = angles_to_unit(np.asarray(self._doa.colatitude_recon)[0], np.asarray(self._doa.azimuth_recon)[0])
        self._last = cast(np.ndarray, direction)  # angles_to_unit returns the type of its inputs
        return self._last


@register_tracker("music")
class MusicTracker(_PyroomacousticsTracker):
    """MUSIC (pyroomacoustics) per frame on the SRP grid, speech band 300-3500 Hz."""

    algorithm = "MUSIC"


@register_tracker("normmusic")
class NormMusicTracker(_PyroomacousticsTracker):
    """MUSIC with frequency normalisation (pyroomacoustics NormMUSIC) per frame on the SRP grid."""

    algorithm = "NormMUSIC"


@register_tracker("srp-pra")
class SrpPraTracker(_PyroomacousticsTracker):
    """pyroomacoustics' SRP-PHAT per frame on the SRP grid, full band (a reference for srp-max)."""

    algorithm = "SRP"
    default_band = (0.0, None)
