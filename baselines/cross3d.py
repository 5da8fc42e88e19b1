"""Cross3D (paper section IV-B, Table I): causal 3D CNN over sequences of SRP-PHAT maps.

Layers for ``(n_theta, n_phi)`` maps, ``L = min(4, floor(log2(min(n_theta, n_phi))))``:

1. Conv3d 3 -> 32, kernel 5x5x5 (time x elevation x azimuth) + PReLU(32).
2. Two branches of L blocks each: Conv3d 32 -> 32, kernel 5x3x3 + PReLU(32) + max-pooling
   ``1x1x2`` (branch "phi", pools azimuth) or ``1x2x1`` (branch "theta", pools elevation).
3. Per frame, the "phi" branch ``(32, n_theta, n_phi / 2^L)`` and the "theta" branch
   ``(32, n_theta / 2^L, n_phi)`` are flattened (channel, elevation, azimuth order) and
   concatenated: ``64 n_theta n_phi / 2^L`` channels of a 1D sequence.
4. Conv1d -> 128, kernel 5, dilation 2 + PReLU (one shared slope).
5. Conv1d 128 -> 3, kernel 5, dilation 2 + tanh.

Every convolution is causal in time (left zero padding only); the map axes are padded to keep
their size ("same"): circular in azimuth, reflecting in elevation.

PReLU slopes: one per channel (32) after each 3D convolution, a single shared one after the
128-channel 1D convolution. This is the only choice that reproduces all five Table I counts (see
docs/models.md): e.g. 16x32 is 1,693,699 weights and biases + 9 x 32 + 1 = 1,693,988.

Receptive field: ``1 + 4 + 4 L + 2 * 8`` frames = 29 (L = 2, 4x8), 33 (8x16) and 37 (L = 4) frames,
i.e. 5.63 s, 6.40 s and 7.17 s with 4096-sample windows and 3072-sample hops, as in Table I.
"""
from __future__ import annotations

import math
from functools import partial

import torch
from torch import nn

from doabench.errors import ConfigError
from .layers import CausalConv, StreamingMixin, max_pool2, number_causal_convs, sphere_pad

CHANNELS = 32
HIDDEN = 128
MAX_BRANCH_LAYERS = 4


def branch_layers(n_theta: int, n_phi: int) -> int:
    """Blocks per branch: 4, or fewer when a map axis has under 16 points (paper IV-B)."""
    return min(MAX_BRANCH_LAYERS, int(math.floor(math.log2(min(n_theta, n_phi)))))


class Cross3D(StreamingMixin, nn.Module):
    """Cross3D for ``(n_theta, n_phi)`` maps.

    ``forward(x)``: ``x`` ``(batch, 3, frames, n_theta, n_phi)`` (normalised map, then the map
    maximum's normalised elevation and azimuth broadcast over the map) -> ``(batch, frames, 3)``
    direction vectors in ``(-1, 1)`` (not normalised). ``stream_step(x_t, state)``: one frame
    ``(batch, 3, n_theta, n_phi)`` -> ``(batch, 3)``.
    """

    def __init__(self, n_theta: int, n_phi: int) -> None:
        super().__init__()
        if n_theta < 3 or n_phi < 3:
            raise ConfigError(f"Cross3D needs maps of at least 3x3 points, got {n_theta}x{n_phi}")
        self.n_theta, self.n_phi = n_theta, n_phi
        self.n_layers = L = branch_layers(n_theta, n_phi)
        self.input = CausalConv(nn.Conv3d(3, CHANNELS, 5), partial(sphere_pad, pad_theta=2, pad_phi=2))
        self.act_input = nn.PReLU(CHANNELS)
        pad1 = partial(sphere_pad, pad_theta=1, pad_phi=1)
        self.branch_phi = nn.ModuleList(CausalConv(nn.Conv3d(CHANNELS, CHANNELS, (5, 3, 3)), pad1) for _ in range(L))
        self.act_phi = nn.ModuleList(nn.PReLU(CHANNELS) for _ in range(L))
        self.branch_theta = nn.ModuleList(CausalConv(nn.Conv3d(CHANNELS, CHANNELS, (5, 3, 3)), pad1) for _ in range(L))
        self.act_theta = nn.ModuleList(nn.PReLU(CHANNELS) for _ in range(L))
        self.n_theta_out, self.n_phi_out = n_theta >> L, n_phi >> L  # floor, as max-pooling does
        self.sequence_channels = CHANNELS * (n_theta * self.n_phi_out + self.n_theta_out * n_phi)
        self.hidden = CausalConv(nn.Conv1d(self.sequence_channels, HIDDEN, 5, dilation=2))
        self.act_hidden = nn.PReLU()  # one shared slope: needed to match Table I
        self.output = CausalConv(nn.Conv1d(HIDDEN, 3, 5, dilation=2))
        self.n_states = number_causal_convs(self)

    @property
    def receptive_field(self) -> int:
        """Frames one output depends on (the current one included)."""
        return 1 + 4 + 4 * self.n_layers + 2 * 8

    @property
    def frame_shape(self) -> tuple[int, int, int]:
        """Shape of one input frame: ``(3, n_theta, n_phi)``."""
        return (3, self.n_theta, self.n_phi)

    def forward(self, x: torch.Tensor, state: list | None = None) -> torch.Tensor:
        """``(batch, 3, frames, n_theta, n_phi)`` -> ``(batch, frames, 3)``; see the module docstring."""
        if x.dim() != 5 or tuple(x.shape[-2:]) != (self.n_theta, self.n_phi) or x.shape[1] != 3:
            raise ConfigError(f"Cross3D {self.n_theta}x{self.n_phi} expects input (batch, 3, frames, "
                              f"{self.n_theta}, {self.n_phi}), got {tuple(x.shape)}")
        h = self.act_input(self.input(x, state))  # (B, 32, T, n_theta, n_phi)
        a = h
        for conv, act in zip(self.branch_phi, self.act_phi):
            a = max_pool2(act(conv(a, state)), -1)  # azimuth
        e = h
        for conv, act in zip(self.branch_theta, self.act_theta):
            e = max_pool2(act(conv(e, state)), -2)  # elevation
        batch, frames = x.shape[0], x.shape[2]
        # (B, C, T, H, W) -> (B, C*H*W, T): each (channel, map cell) becomes one input sequence.
        seq = torch.cat([
            a.permute(0, 1, 3, 4, 2).reshape(batch, -1, frames),
            e.permute(0, 1, 3, 4, 2).reshape(batch, -1, frames),
        ], dim=1)
        y = torch.tanh(self.output(self.act_hidden(self.hidden(seq, state)), state))  # (B, 3, T)
        return y.transpose(1, 2)


def cross3d_input(srp: torch.Tensor, srp_max: torch.Tensor) -> torch.Tensor:
    """Build the 3-channel input from maps and their maxima.

    ``srp`` ``(..., n_theta, n_phi)`` and ``srp_max`` ``(..., 2)`` (normalised elevation, azimuth)
    -> ``(..., 3, n_theta, n_phi)``: the map, then each coordinate broadcast over the map.
    """
    shape = srp.shape
    el = srp_max[..., 0, None, None].expand(shape)
    az = srp_max[..., 1, None, None].expand(shape)
    return torch.stack([srp, el.to(srp.dtype), az.to(srp.dtype)], dim=-3)


def widen_state(state: dict[str, torch.Tensor], source: tuple[int, int], target: tuple[int, int]) -> dict[str, torch.Tensor]:
    """Weights of Cross3D on ``source`` maps -> a starting point for Cross3D on finer ``target`` maps.

    Every 3D convolution has the same shape at every resolution and is copied. The 1D layer's input
    grows with the pooled grid: its weights ``(128, C_source, 5)`` are split into the two branches'
    ``(channel, elevation, azimuth)`` cells, each cell's weights repeated over the ``f_theta x f_phi``
    finer cells that cover the same directions and divided by ``f_theta f_phi``, so that a map whose
    finer cells repeat the coarse ones gives the source's 1D input exactly. Needs both resolutions
    to have the same number of branch blocks and ``target`` to be a whole multiple of ``source``.
    Returns ``(128, C_target, 5)`` for ``hidden.conv.weight`` and the other tensors unchanged.
    """
    (st, sp), (tt, tp) = source, target
    layers = branch_layers(st, sp)
    if branch_layers(tt, tp) != layers or tt % st or tp % sp:
        raise ConfigError(f"Cross3D {tt}x{tp} cannot start from {st}x{sp} weights: the finer map must be a whole "
                          f"multiple of the coarser one with as many pooling blocks ({layers})")
    ft, fp = tt // st, tp // sp
    key = next(k for k in state if k.startswith("hidden.") and k.endswith("weight"))
    w = state[key]  # (128, C_source, 5)
    phi_cells = st * (sp >> layers)  # the "phi" branch: (channel, n_theta, n_phi / 2^L)
    out, _, k = w.shape
    a = w[:, :CHANNELS * phi_cells].reshape(out, CHANNELS, st, sp >> layers, k)
    e = w[:, CHANNELS * phi_cells:].reshape(out, CHANNELS, st >> layers, sp, k)

    def spread(x: torch.Tensor) -> torch.Tensor:
        return x.repeat_interleave(ft, dim=2).repeat_interleave(fp, dim=3).reshape(out, -1, k)

    widened = dict(state)
    widened[key] = torch.cat([spread(a), spread(e)], dim=1) / (ft * fp)
    return widened
