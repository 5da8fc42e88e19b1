"""A feature kind as a plug-in: the log energy of each microphone in each frame.

Register it from Python (``register_feature_kind(FRAME_ENERGY)``) or declare it in your package's
``pyproject.toml``, and every layer offers it: ``gymnasium.make(..., features=("srp", "frame_energy"))``,
a tracker's ``observation_spec`` (``ObservationSpec.of(("frame_energy",))``), ``doabench track`` and
training.

    [project.entry-points."doabench.feature_kinds"]
    frame_energy = "frame_energy:FRAME_ENERGY"
"""
import torch

from doabench.features import FeatureKind


def log_energy(stft) -> torch.Tensor:
    """``stft``: the pass's shared STFTContext (its framed samples, spectra, GCC, maps, ...) ->
    ``(batch, frames, n_mics)``: log10 of each frame's mean square."""
    frames = stft.frames  # (batch, frames, n_mics, window), a view of the recording
    return frames.pow(2).mean(-1).clamp_min(1e-12).log10()


FRAME_ENERGY = FeatureKind(
    "frame_energy",
    frame_shape=lambda context: (context.array.n_mics,),  # one value per microphone
    compute=log_energy,
    description="log10 mean square of each microphone's frame",
)
