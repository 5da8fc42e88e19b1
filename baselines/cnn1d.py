"""The paper's 1D CNN baselines (section V-A, Table I): ``gcc-cnn1d`` and ``max-cnn1d``.

Seven causal Conv1d layers with ``{1024, 512, 512, 512, 512, 128, 3}`` output channels, kernel 5,
dilation 1 for the first five and 2 for the last two, PReLU after all but the last (tanh). No
pooling. Receptive field ``1 + 5 * 4 + 2 * 8 = 37`` frames (7.17 s), as Cross3D's.

PReLU slopes: one per channel after the five wide layers, one shared after the 128-channel layer
(the same rule as Cross3D; it is what makes both Table I counts exact):

* ``max-cnn1d``: 2 input sequences (normalised elevation and azimuth of each map's maximum):
  6,896,643 weights and biases + 1024 + 4 x 512 + 1 = 6,899,716.
* ``gcc-cnn1d``: one input sequence per (microphone pair, lag) with ``|lag| <= max_lag``; the NAO
  array has 66 pairs and ``max_lag = ceil(0.1208 m / 343 m/s * 16 kHz) = 6``, so 66 x 13 = 858
  inputs: 11,282,436 parameters. Channel order: pair-major, lag-minor (``pair * n_lags + lag``),
  i.e. the observation ``gcc`` ``(n_pairs, n_lags)`` flattened.
"""
from __future__ import annotations

import torch
from torch import nn

from doabench.errors import ConfigError

from .layers import CausalConv, StreamingMixin, number_causal_convs

CHANNELS = (1024, 512, 512, 512, 512, 128, 3)
DILATIONS = (1, 1, 1, 1, 1, 2, 2)
KERNEL = 5


class CausalCnn1d(StreamingMixin, nn.Module):
    """The 7-layer causal 1D CNN over ``in_channels`` time sequences.

    ``forward(x)``: ``(batch, in_channels, frames)`` -> ``(batch, frames, 3)`` in ``(-1, 1)``.
    ``stream_step(x_t, state)``: ``(batch, in_channels)`` -> ``(batch, 3)``.
    """

    def __init__(self, in_channels: int) -> None:
        super().__init__()
        if in_channels < 1:
            raise ConfigError(f"a 1D CNN needs at least one input sequence, got {in_channels}")
        self.in_channels = in_channels
        sizes = (in_channels,) + CHANNELS
        self.convs = nn.ModuleList(
            CausalConv(nn.Conv1d(c_in, c_out, KERNEL, dilation=d))
            for c_in, c_out, d in zip(sizes[:-1], sizes[1:], DILATIONS)
        )
        # Per-channel slopes on the wide layers, a single shared slope on the 128-channel layer.
        self.acts = nn.ModuleList([nn.PReLU(c) for c in CHANNELS[:-2]] + [nn.PReLU()])
        self.n_states = number_causal_convs(self)

    @property
    def receptive_field(self) -> int:
        return 1 + sum((KERNEL - 1) * d for d in DILATIONS)

    @property
    def frame_shape(self) -> tuple[int]:
        return (self.in_channels,)

    def forward(self, x: torch.Tensor, state: list | None = None) -> torch.Tensor:
        if x.dim() != 3 or x.shape[1] != self.in_channels:
            raise ConfigError(f"1D CNN expects input (batch, {self.in_channels}, frames), got {tuple(x.shape)}")
        for conv, act in zip(self.convs[:-1], self.acts):
            x = act(conv(x, state))
        return torch.tanh(self.convs[-1](x, state)).transpose(1, 2)


def gcc_cnn1d(n_pairs: int = 66, n_lags: int = 13) -> CausalCnn1d:
    """``gcc-cnn1d``: input ``(batch, n_pairs * n_lags, frames)`` (defaults: the NAO array)."""
    return CausalCnn1d(n_pairs * n_lags)


def max_cnn1d() -> CausalCnn1d:
    """``max-cnn1d``: input ``(batch, 2, frames)``, the normalised (elevation, azimuth) of the maxima."""
    return CausalCnn1d(2)
