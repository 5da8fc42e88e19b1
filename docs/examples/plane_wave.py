"""A task kind as a plug-in: far-field plane waves of white noise from one direction per episode, no room.

A check that needs no simulator: every tracker should find a plane wave's direction to within its grid.
Declare it in your package's ``pyproject.toml`` (or call ``doabench.register_task_kind``), then write
tasks of this kind as any other (``kind = "plane-wave"``, ``[plane_wave] duration_s = 4``):

    [project.entry-points."doabench.task_kinds"]
    plane-wave = "plane_wave:PlaneWaveEpisodes"
"""
from dataclasses import dataclass

import numpy as np

import doabench
from doabench.geometry import SPEED_OF_SOUND


@dataclass(frozen=True)
class PlaneWaveOptions:
    """The run-time options of a plane-wave task (``gymnasium.make(..., snr_db=10)``)."""

    snr_db: float | None = None  # white noise on every microphone at this SNR (None: no noise)


class PlaneWaveEpisodes:
    """Episode ``i``: white noise arriving as a plane wave from a direction drawn from ``(base_seed, i)``."""

    Options = PlaneWaveOptions
    headline = "pooled"  # the RMSAE over every frame

    def __init__(self, spec, **options):
        self.spec, self.options = spec, PlaneWaveOptions(**options)
        self.array = doabench.get_array(spec.array)
        self.duration_s = float(spec.params.get("plane_wave", {}).get("duration_s", 4.0))

    def __len__(self) -> int:
        return self.spec.episodes

    def episode(self, index: int) -> doabench.Episode:
        rng = np.random.default_rng([self.spec.base_seed, index])
        direction = rng.standard_normal(3)
        if self.array.planar:  # a planar array cannot tell up from down: keep to the upper half
            direction[2] = abs(direction[2])
        direction /= np.linalg.norm(direction)
        fs = self.spec.frames.fs
        n = int(self.duration_s * fs)
        # a plane wave from `direction` reaches a microphone at p earlier by p . direction / c
        advance = (self.array.positions - self.array.positions.mean(0)) @ direction / SPEED_OF_SOUND
        spectrum = np.fft.rfft(rng.standard_normal(n))
        f = np.fft.rfftfreq(n, 1 / fs)
        audio = np.fft.irfft(spectrum * np.exp(2j * np.pi * f * advance[:, None]), n)
        if self.options.snr_db is not None:
            audio += rng.standard_normal(audio.shape) * audio.std() * 10 ** (-self.options.snr_db / 20)
        return doabench.Episode(audio.astype(np.float32), fs, sample_vad=np.ones(n, bool),
                                sample_directions=np.tile(direction, (n, 1)),
                                metadata={"episode_index": index, "direction": direction.tolist()})

    def describe(self) -> dict:
        return {"plane_wave": {"duration_s": self.duration_s}, "snr_db": self.options.snr_db}
