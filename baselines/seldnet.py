"""``seldnet``: the DOA branch of SELDnet (Adavanne et al., 2019) as the paper's baseline (V-A).

Non-causal (bidirectional GRUs), whole sequences only. Input ``(batch, 2 n_mics, frames, n_freq)``
spectrograms (magnitude then phase / pi, DC dropped); the paper's K = 512 windows give 256 bins,
the NAO array 24 channels.

1. Three blocks: Conv2d 64 kernels 3x3 ("same" zero padding in time and frequency) + batch
   normalisation + ReLU + max-pooling over frequency only, by 8, 8 and 4 (256 -> 32 -> 4 -> 1).
   This is SELDnet's convolutional block (64 filters of 3x3, BN, ReLU, frequency-only pooling).
2. The ``64 x 1`` features of each frame feed two bidirectional GRU layers of 16 units; as in
   SELDnet's reference implementation the two directions are merged by elementwise product.
3. Fully connected 16 -> 256 + PReLU (one slope per unit), then fully connected 256 -> 3 + tanh.

Table I gives 104,643 parameters, far fewer than SELDnet's defaults (64 filters, pooling 8/8/2,
128-unit GRUs, a 128-unit dense layer: 501,315 parameters with these inputs), so the replica was
scaled down; the text fixes only the layer types. This configuration keeps SELDnet's
convolutional layers (only the last pooling is 4 instead of 2, leaving one bin) and gives the
table's count exactly: 88,128 (convolutions + BN) + 11,136 (GRUs, PyTorch's two bias vectors
per gate) + 4,352 + 256 + 771 (dense layers and slopes). The solution is not unique;
docs/models.md lists other configurations that also give 104,643.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from doabench.errors import ConfigError

FILTERS = 64
POOLS = (8, 8, 4)
GRU_UNITS = 16
FC_UNITS = 256


class Seldnet(nn.Module):
    """``forward(x)``: ``(batch, in_channels, frames, n_freq)`` -> ``(batch, frames, 3)`` in (-1, 1)."""

    def __init__(self, in_channels: int = 24, n_freq: int = 256) -> None:
        super().__init__()
        pooled = n_freq
        for p in POOLS:
            pooled //= p
        if pooled < 1:
            raise ConfigError(f"seldnet needs at least {8 * 8 * 4} frequency bins, got {n_freq}")
        self.in_channels, self.n_freq, self.n_freq_out = in_channels, n_freq, pooled
        sizes = (in_channels,) + (FILTERS,) * len(POOLS)
        self.convs = nn.ModuleList(nn.Conv2d(a, b, 3, padding=1) for a, b in zip(sizes[:-1], sizes[1:]))
        self.norms = nn.ModuleList(nn.BatchNorm2d(FILTERS) for _ in POOLS)
        self.gru1 = nn.GRU(FILTERS * pooled, GRU_UNITS, batch_first=True, bidirectional=True)
        self.gru2 = nn.GRU(GRU_UNITS, GRU_UNITS, batch_first=True, bidirectional=True)
        self.fc = nn.Linear(GRU_UNITS, FC_UNITS)
        self.act_fc = nn.PReLU(FC_UNITS)
        self.output = nn.Linear(FC_UNITS, 3)

    @property
    def receptive_field(self) -> None:
        return None  # bidirectional recurrences see the whole sequence

    @staticmethod
    def _merge(h: torch.Tensor) -> torch.Tensor:
        """``(batch, frames, 2 units)`` (forward | backward) -> their product ``(batch, frames, units)``."""
        forward, backward = h.chunk(2, dim=-1)
        return forward * backward

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.dim() != 4 or x.shape[1] != self.in_channels or x.shape[3] != self.n_freq:
            raise ConfigError(f"seldnet expects input (batch, {self.in_channels}, frames, {self.n_freq}), "
                              f"got {tuple(x.shape)}")
        for conv, norm, p in zip(self.convs, self.norms, POOLS):
            x = F.max_pool2d(F.relu(norm(conv(x))), (1, p))
        batch, frames = x.shape[0], x.shape[2]
        h = x.permute(0, 2, 1, 3).reshape(batch, frames, -1)  # (B, T, 64 * F_out)
        h = self._merge(self.gru1(h)[0])
        h = self._merge(self.gru2(h)[0])
        h = self.fc(h)
        # nn.PReLU puts its slopes on axis 1; here the units are on the last axis.
        h = torch.where(h >= 0, h, self.act_fc.weight * h)
        return torch.tanh(self.output(h))
