"""A simulator backend as a plug-in: the free field (no walls, no echoes), a reference against which
to measure what a room's reflections cost a tracker.

Register it from Python (``register_simulator("free-field", FreeFieldSimulator)``) or declare it in
your package's ``pyproject.toml``; then ``--backend free-field`` (or ``backend="free-field"`` in
``gymnasium.make``) renders any simulated task with it.

    [project.entry-points."doabench.simulators"]
    free-field = "free_field:FreeFieldSimulator"
"""
import numpy as np
import torch

from doabench.acoustics import rir
from doabench.acoustics.backends.base import TorchBackend


class FreeFieldSimulator(TorchBackend):
    """The direct path alone: amplitude ``1 / (4 pi r)``, delay ``r / c``. ``TorchBackend`` brings
    the validation, the trajectory's segments and their overlap-add; a backend gives the RIRs."""

    name = "free-field"

    def __init__(self, device: torch.device | str | None = None) -> None:
        self.device = rir.resolve_device(device)

    def versions(self) -> dict[str, str]:
        return {"backend": self.name, "torch": torch.__version__}

    def rirs_tensor(self, room, sources: np.ndarray, mics: np.ndarray, fs: int, generator) -> torch.Tensor:
        """RIRs ``(S, M, taps)`` float32 from ``sources (S, 3)`` to ``mics (M, 3)`` (or ``(S, M, 3)``
        for a moving array), room coordinates."""
        return rir.direct_rirs(torch.as_tensor(sources, device=self.device),
                               torch.as_tensor(mics, device=self.device), fs)
