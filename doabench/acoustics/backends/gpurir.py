"""``gpurir``: a thin wrapper of gpuRIR, the library the Cross3D paper used, when it is importable."""
from __future__ import annotations

import numpy as np
import torch

from doabench.acoustics import compute
from doabench.acoustics import rir_model
from doabench.acoustics.backends.base import TorchBackend
from doabench.acoustics.room import Room
from doabench.errors import ConfigError, DependencyError


GPURIR_INSTALL = (
    "gpuRIR is not installed: it is not on PyPI and needs an NVIDIA GPU with the CUDA toolkit; "
    "install it from its GitHub repository with "
    "`pip install https://github.com/DavidDiazGuerra/gpuRIR/zipball/master`"
)


class GpuRIRSimulator(TorchBackend):
    """Thin wrapper of gpuRIR's public API (``beta_SabineEstimation``, ``att2t_SabineEstimator``,
    ``t2n``, ``simulateRIR`` with ``Tdiff``/``Tmax``). Amplitudes and tail are gpuRIR's own; its
    tail noise is drawn on the GPU by gpuRIR and ``seed`` has no effect on it."""

    name = "gpurir"

    def __init__(self, device: str | torch.device | None = None) -> None:
        try:
            import gpuRIR
        except ImportError:
            raise DependencyError(GPURIR_INSTALL) from None
        self._gpurir = gpuRIR
        self.device = compute.resolve_device(device)

    def versions(self) -> dict[str, str]:
        return {
            "backend": self.name,
            "gpuRIR": str(getattr(self._gpurir, "__version__", "unknown")),
            "torch": torch.__version__,
        }

    def rirs_tensor(self, room: Room, sources: np.ndarray, mics: np.ndarray, fs: int, generator) -> torch.Tensor:
        g = self._gpurir
        if np.ndim(mics) == 3:
            raise ConfigError("the gpurir backend simulates static arrays only; use builtin or pyroomacoustics "
                              "for a moving array")
        dims = np.asarray(room.dims)
        if room.t60 == 0:
            beta = np.zeros(6)
            n_img = [1, 1, 1]
            delays = rir_model.direct_delays(torch.as_tensor(sources), torch.as_tensor(mics), fs)
            t_diff = None
            t_max = rir_model.rir_layout(None, float(delays.max()), fs).n_taps / fs
        else:
            beta = g.beta_SabineEstimation(dims, room.t60, np.asarray(room.abs_weights))
            t_diff = g.att2t_SabineEstimator(12, room.t60)
            t_max = g.att2t_SabineEstimator(40, room.t60)
            n_img = g.t2n(t_diff, dims)
        kwargs = {} if t_diff is None else {"Tdiff": t_diff}
        h = g.simulateRIR(dims, beta, np.asarray(sources), np.asarray(mics), n_img, t_max, fs, **kwargs)
        return torch.as_tensor(np.asarray(h, dtype=np.float32), device=self.device)
