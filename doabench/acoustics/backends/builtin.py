"""``builtin``: doabench's torch image-source engine (:mod:`doabench.acoustics.rir`), CPU or CUDA."""
from __future__ import annotations

import numpy as np
import torch

from doabench.acoustics import compute
from doabench.acoustics import rir as engine
from doabench.acoustics import rir_model
from doabench.acoustics.backends.base import TorchBackend
from doabench.acoustics.convolution import cpu_fft_backend
from doabench.acoustics.room import Room


class BuiltinSimulator(TorchBackend):
    """doabench's torch image-source engine (see :mod:`doabench.acoustics.rir`)."""

    name = "builtin"

    def __init__(self, device: str | torch.device | None = None) -> None:
        self.device = compute.resolve_device(device)

    def versions(self) -> dict[str, str]:
        from doabench._version import __version__

        return {
            "backend": self.name,
            "doabench": __version__,
            "torch": torch.__version__,
            "device": str(self.device),
            "sinc": f"hann-windowed over +-{rir_model.SINC_HALF} samples; arrival at the nearest 1/"
                    f"{engine.KERNEL_PHASES} sample (image_kernel c) or linear between 1/{engine.OVERSAMPLE}-sample "
                    "phases (image_kernel torch)",
            "hpf": "none",
            "tail": rir_model.TAIL_MODEL,
            "image_kernel": engine.image_kernel(self.device),
            "fft": cpu_fft_backend() if self.device.type == "cpu" else "torch",
        }

    def rirs_parts(
        self, room: Room, sources: np.ndarray, mics: np.ndarray, fs: int, generator, width: int | None = None
    ) -> rir_model.RirParts:
        src = torch.tensor(sources, device=self.device)
        mic = torch.tensor(mics, device=self.device)
        return engine.image_source_parts(room, src, mic, fs, generator, width)
