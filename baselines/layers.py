"""Building blocks shared by the models: spherical padding, causal temporal convolutions with a
streaming cache, and the receptive-field bookkeeping.

Every model lays its tensors out as ``(batch, channels, frames, *space)`` with time on axis 2, so
one :class:`CausalConv` wraps ``nn.Conv1d`` (no space), ``nn.Conv2d`` (one space axis, e.g.
frequency) and ``nn.Conv3d`` (two, the SRP map).

Streaming: a model's ``forward(x, state)`` takes an optional *state*, a list with one slot per
:class:`CausalConv` (numbered in construction order by :func:`number_causal_convs`). With
``state=None`` the time axis is left-padded with zeros (the full-sequence pass). With a state, each
layer prepends the last ``(kernel - 1) * dilation`` input frames it saw (zeros before the first
call) and stores the newest ones back, so feeding a sequence in chunks of any length, one frame at
a time included, gives the same outputs as one full pass while each call costs only its own frames.
"""
from __future__ import annotations

from typing import Callable, Optional

import torch
import torch.nn.functional as F
from torch import nn

State = list  # list[Optional[torch.Tensor]], one cached block of frames per CausalConv


def sphere_pad(x: torch.Tensor, pad_theta: int, pad_phi: int) -> torch.Tensor:
    """Pad the two map axes of ``(..., n_theta, n_phi)``: reflecting in elevation, circular in azimuth.

    The azimuth grid covers ``[-pi, pi)`` exactly, so its ends are neighbours (circular); elevation
    stops at the poles, where reflection (edge row not repeated) keeps the padded rows plausible
    map values. Needs ``pad_theta < n_theta`` and ``pad_phi <= n_phi``.
    Returns ``(..., n_theta + 2 pad_theta, n_phi + 2 pad_phi)``.
    """
    # Concatenated slices rather than F.pad's reflect/circular modes: the same values (tested),
    # but torch.compile turns these into plain copies, while its code for the padding modes (and
    # their backward) took half of a compiled Cross3D 16x32 training step: 0.48 -> 0.24 CPU-s
    # per trajectory (docs/performance.md).
    if pad_theta:
        top = x[..., 1 : pad_theta + 1, :].flip(-2)  # rows 1..p mirrored; the edge row is not repeated
        bottom = x[..., -pad_theta - 1 : -1, :].flip(-2)
        x = torch.cat([top, x, bottom], dim=-2)
    if pad_phi:
        x = torch.cat([x[..., -pad_phi:], x, x[..., :pad_phi]], dim=-1)  # azimuth wraps around
    return x


def max_pool2(x: torch.Tensor, dim: int) -> torch.Tensor:
    """Max-pooling by 2 (stride 2, odd remainder dropped) along one axis.

    The same as ``max_pool3d`` with a ``1x1x2`` / ``1x2x1`` kernel, several times faster on CPU
    because it needs no index bookkeeping: the max of the even and the odd slices.
    """
    dim = dim % x.dim()
    n = x.shape[dim] // 2 * 2
    lead = (slice(None),) * dim
    return torch.maximum(x[lead + (slice(0, n, 2),)], x[lead + (slice(1, n, 2),)])


def zero_pad_last(x: torch.Tensor, pad: int) -> torch.Tensor:
    """Zero "same" padding of the last axis (frequency in the spectrogram models)."""
    return F.pad(x, (pad, pad)) if pad else x


class CausalConv(nn.Module):
    """A convolution over ``(batch, channels, frames, *space)`` that is causal along frames.

    ``conv`` must be built with ``padding=0``; its first kernel/dilation entries are the temporal
    ones. ``space_pad`` (optional) pads the spatial axes of every frame before the convolution
    ("same" spatial size). Output: ``(batch, out_channels, frames, *space_out)``.
    """

    def __init__(self, conv: nn.Module, space_pad: Optional[Callable[[torch.Tensor], torch.Tensor]] = None) -> None:
        super().__init__()
        self.conv = conv
        self.space_pad = space_pad
        self.kernel = int(conv.kernel_size[0])
        self.dilation = int(conv.dilation[0])
        #: past input frames each output needs besides the current one
        self.context = (self.kernel - 1) * self.dilation
        self.slot = -1  # index in the streaming state, set by number_causal_convs

    def forward(self, x: torch.Tensor, state: Optional[State] = None) -> torch.Tensor:
        if self.space_pad is not None:
            x = self.space_pad(x)
        if self.context:
            if state is None:
                pad = [0, 0] * (x.dim() - 3) + [self.context, 0]  # F.pad lists the last axis first
                x = F.pad(x, pad)
            else:
                cached = state[self.slot]
                if cached is None:  # first frame of a stream: the same zeros the full pass pads
                    cached = x.new_zeros(x.shape[:2] + (self.context,) + x.shape[3:])
                x = torch.cat([cached, x], dim=2)
                # Cache padded frames so the spatial padding is done once per frame.
                state[self.slot] = x[:, :, -self.context:].contiguous()
                if x.shape[2] == self.context + 1:
                    return self._one_frame(x)
        return self.conv(x)

    def _one_frame(self, window: torch.Tensor) -> torch.Tensor:
        """The single output frame of a ``(batch, C, context + 1, *space)`` window.

        A temporal kernel that spans the whole window is the same as folding time into the
        channels: a Conv3d becomes a Conv2d, a Conv2d a Conv1d, a Conv1d a matrix product. The
        lower-dimensional kernels are several times faster than the general ones on one frame.
        """
        taps = window[:, :, :: self.dilation] if self.dilation > 1 else window  # (B, C, k, *S)
        b = taps.shape[0]
        weight = self.conv.weight  # (C_out, C_in, k, *kernel_space), contiguous: reshapes are views
        folded = taps.reshape(b, -1, *taps.shape[3:])
        w = weight.reshape(weight.shape[0], -1, *weight.shape[3:])
        if window.dim() == 3:
            y = F.linear(folded, w, self.conv.bias)
        elif window.dim() == 4:
            y = F.conv1d(folded, w, self.conv.bias)
        else:
            y = F.conv2d(folded, w, self.conv.bias)
        return y.unsqueeze(2)


def number_causal_convs(model: nn.Module) -> int:
    """Give each :class:`CausalConv` of ``model`` its state slot; returns how many there are."""
    layers = [m for m in model.modules() if isinstance(m, CausalConv)]
    for i, m in enumerate(layers):
        m.slot = i
    return len(layers)


class StreamingMixin:
    """``stream_step`` / ``init_state`` for models whose ``forward(x, state)`` follows the module
    docstring. Subclasses set ``n_states`` (from :func:`number_causal_convs`) and implement
    ``forward``; ``stream_step`` adds and removes the length-1 time axis."""

    n_states: int = 0

    def init_state(self) -> State:
        """A fresh stream: every layer's cache starts as the zeros of causal padding."""
        return [None] * self.n_states

    def stream_step(self, x_t: torch.Tensor, state: State) -> tuple[torch.Tensor, State]:
        """One new frame ``(batch, *frame_shape)`` -> output ``(batch, 3)`` and the updated state.

        The given state list is not modified; a new one is returned.
        """
        state = list(state)
        y = self.forward(x_t.unsqueeze(2), state)  # (batch, 1, 3)
        return y[:, 0], state

    def stream_chunk(self, x: torch.Tensor, state: State) -> tuple[torch.Tensor, State]:
        """Several new frames ``(batch, C, frames, ...)`` -> ``(batch, frames, 3)`` and the state."""
        state = list(state)
        return self.forward(x, state), state


def count_parameters(model: nn.Module) -> int:
    """Trainable parameters (works on models built on the ``meta`` device)."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)


def receptive_field_seconds(frames: int, window: int = 4096, hop: int = 3072, fs: int = 16000) -> float:
    """Time spanned by ``frames`` consecutive windows: ``((frames - 1) hop + window) / fs``."""
    return ((frames - 1) * hop + window) / fs
