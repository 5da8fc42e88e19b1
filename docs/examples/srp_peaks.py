"""A map kind as a plug-in: the SRP-PHAT map's peaks, on the SRP grid, and a tracker that reads it.

A kind on the grid (``on_grid=True``) takes ``MapConfig``, the grid and delays every map carries:
``ObservationSpec.of(("srp_peaks",), "16x32")`` is ``srp_peaks(grid=16x32, delays=nearest)``, its
observation is ``(16, 32)`` a frame, ``make-dataset --features srp_peaks:16x32`` stores it at
``features/srp_peaks_16x32``.

    [project.entry-points."doabench.feature_kinds"]
    srp_peaks = "srp_peaks:SRP_PEAKS"
"""
import numpy as np
import torch

import doabench
from doabench.features import FeatureKind
from doabench.geometry import grid_unit_vectors


def peaks(stft) -> torch.Tensor:
    """``stft``: the pass's shared STFTContext -> ``(batch, frames, n_theta, n_phi)``: the map
    (mean removed, divided by its maximum) below zero cut away, then squared, so that the
    strongest cells stand out."""
    return stft.maps.clamp_min(0).square()


SRP_PEAKS = FeatureKind(
    "srp_peaks",
    frame_shape=lambda context: tuple(context.resolution),  # the grid the spec names
    low=0.0,
    high=1.0,
    compute=peaks,
    stages=("srp",),  # it reads the shared SRP maps (context.maps)
    on_grid=True,
    config=doabench.MapConfig,
    description="SRP-PHAT map peaks: the map's positive part, squared",
)


class PeakTracker(doabench.Tracker):
    """The cell of the highest peak; holds its estimate where the map is empty."""

    def __init__(self, spec=None, **options):
        super().__init__(spec, **options)
        # what it reads, as one value: the peaks on the grid its spec names (16x32 without one)
        self.observation_spec = doabench.ObservationSpec.of(("srp_peaks",), spec or "16x32")

    def reset(self, array, **context):
        self.grid = grid_unit_vectors(*self.resolution, planar=array.planar).reshape(-1, 3)
        self.last = np.array([1.0, 0.0, 0.0])

    def step(self, observation):
        cells = observation["srp_peaks"].ravel()
        if cells.any():
            self.last = self.grid[int(np.argmax(cells))]
        return self.last
