"""The torch device a learned tracker runs on (``--tracker-opt device=cpu|cuda[:N]``)."""
from __future__ import annotations

from typing import TYPE_CHECKING

from doabench.errors import ConfigError

if TYPE_CHECKING:
    import torch


def torch_device(text: str) -> torch.device:
    """``cpu`` or ``cuda[:N]`` as a torch device; a one-line ConfigError for anything else or for
    CUDA where torch has none."""
    import torch

    try:
        device = torch.device(text)
    except (RuntimeError, TypeError):
        raise ConfigError(f"unknown device {text!r}: use cpu or cuda[:N]") from None
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"device {text!r} requested but CUDA is not available; use device=cpu")
    if device.type not in ("cpu", "cuda"):
        raise ConfigError(f"unsupported device {text!r}: use cpu or cuda[:N]")
    return device
