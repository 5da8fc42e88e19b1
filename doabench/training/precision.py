"""How the network's arithmetic runs: the training device, bf16 autocast or float32, and the
tensor layout for compiled 3D convolutions.

A run's precision is chosen once per invocation (:func:`resume_precision`) and then applied by a
:class:`PrecisionPolicy` to every forward pass and every tensor moved to the device. Autocast only
rounds activations: master weights, loss and Adam state stay float32, so the checkpoint is the
same in either precision.
"""
from __future__ import annotations

import contextlib
from dataclasses import dataclass
from typing import ContextManager

import torch

from doabench.errors import ConfigError

PRECISIONS = ("auto", "bf16", "fp32")


def cpu_has_native_bf16() -> bool:
    """True where oneDNN runs bf16 natively (AVX-512 BF16 or AMX): there autocast pays off."""
    try:
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):
        return False


def training_device(name: str) -> torch.device:
    """The device ``--device`` names; a one-line error for CUDA where torch has none."""
    device = torch.device(name)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError("--device cuda requested but torch has no CUDA device here")
    return device


def resolve_precision(precision: str, device: torch.device) -> str:
    """``bf16`` or ``fp32`` for a requested ``auto``, ``bf16`` or ``fp32`` on ``device``."""
    if precision not in PRECISIONS:
        raise ConfigError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    if precision == "auto":
        return "bf16" if device.type == "cuda" or cpu_has_native_bf16() else "fp32"
    return precision


def resume_precision(saved: str | None, requested: str, device: torch.device,
                     started_in: str | None = None) -> tuple[str, str | None]:
    """The precision a run trains in, and a note to print when it is not the run's saved one.

    A new run (``saved`` None) resolves ``requested``. A resumed run keeps its precision, except
    that an explicit ``--precision`` wins (the checkpoint is the same either way, see the module
    docstring) and that ``auto`` falls back to fp32 for a bf16 run resumed on a CPU without native
    bf16, where autocast is emulated: 12.8x slower than float32 for a Cross3D 4x8 step on an
    AVX2-only AMD EPYC (docs/training.md). That fallback is the machine's, not the run's:
    ``started_in`` (the precision of the run's first epoch) says which precision the run is, so a
    bf16 run that went on in fp32 on such a CPU goes back to bf16 on the next one that has it
    (before this rule cross3d-16x32-v3, a bf16 run with 17 fp32 epochs from AVX2-only CPUs,
    resumed in fp32 on an AVX-512 BF16 CPU)."""
    if saved is None:
        return resolve_precision(requested, device), None
    if requested != "auto":
        precision = resolve_precision(requested, device)
        if precision == saved:
            return precision, None
        return precision, f"note: the run trained in {saved} so far; it continues in {precision} (--precision)"
    if "bf16" not in (saved, started_in):
        return saved, None
    if device.type == "cpu" and not cpu_has_native_bf16():
        if saved == "fp32":
            return "fp32", None
        return "fp32", ("note: the run trained in bf16 so far, but this CPU has no native bf16 (autocast would be "
                        "emulated, about 13x slower): it continues in fp32 (--precision bf16 forces bf16)")
    if saved != "bf16":
        return "bf16", ("note: the run started in bf16 and went on in fp32 on a CPU without native bf16; this "
                        "device has it, so it continues in bf16 (--precision fp32 keeps fp32)")
    return "bf16", None


@dataclass(frozen=True)
class PrecisionPolicy:
    """Where and in which arithmetic the network runs: ``precision`` ``bf16`` or ``fp32``;
    ``channels_last``: 5D tensors in channels-last layout, which oneDNN's fast (AMX) 3D
    convolutions want (only for a compiled network with 3D convolutions)."""

    device: torch.device
    precision: str
    channels_last: bool = False

    @classmethod
    def for_network(cls, network: torch.nn.Module, device: torch.device, precision: str,
                    compile: bool) -> "PrecisionPolicy":
        channels_last = bool(compile) and any(isinstance(m, torch.nn.Conv3d) for m in network.modules())
        return cls(device, precision, channels_last)

    def place(self, network: torch.nn.Module) -> None:
        """Move ``network`` to the device (and layout) in place."""
        network.to(self.device)
        if self.channels_last:
            # Module.to documents memory_format (keyword only); torch's overloads leave it out.
            network.to(memory_format=torch.channels_last_3d)  # type: ignore[call-overload]

    def autocast(self) -> ContextManager:
        """The context of a forward pass: bf16 activations, or nothing for float32."""
        if self.precision != "bf16":
            return contextlib.nullcontext()
        return torch.autocast(self.device.type, dtype=torch.bfloat16)

    def to_device(self, x: torch.Tensor) -> torch.Tensor:
        x = x.to(self.device, non_blocking=True)
        if self.channels_last and x.dim() == 5:
            x = x.contiguous(memory_format=torch.channels_last_3d)
        return x
