"""A complete third-party tracker: the power-weighted centroid of the strongest SRP-PHAT cells.

Run it without editing doabench:
    doabench run --tracker centroid_tracker:CentroidTracker --task sim-demo
(with this folder on PYTHONPATH), or after `import centroid_tracker` as `--tracker srp-centroid`.
"""
import numpy as np

import doabench
from doabench.geometry import grid_unit_vectors


@doabench.register_tracker("srp-centroid")
class CentroidTracker(doabench.Tracker):
    # what it reads, as one value: SRP-PHAT maps on the 16x32 grid, on the default frames
    observation_spec = doabench.ObservationSpec.of(("srp",), "16x32")
    causal = True

    def __init__(self, spec=None, top=5, **options):
        super().__init__(spec, **options)
        self.top = int(top)

    def reset(self, array, **context):
        self.grid = grid_unit_vectors(*self.resolution, planar=array.planar).reshape(-1, 3)
        self.last = np.array([1.0, 0.0, 0.0])

    def step(self, observation):
        srp = observation["srp"].ravel()
        if observation["vad"] and srp.any():  # silent frames carry no direction: hold
            best = np.argsort(srp)[-self.top:]
            self.last = (np.clip(srp[best], 0, None)[:, None] * self.grid[best]).sum(0) + 1e-9 * self.grid[best[-1]]
        return self.last / np.linalg.norm(self.last)
