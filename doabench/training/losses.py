"""Training losses, as pure tensor functions.

The paper (section IV-C) trains on the mean squared error between the network's output and the
truth's Cartesian unit vector at every frame. Beyond the paper, :func:`tracking_loss` may add a term on
the frame-to-frame change: the MSE between the output's and the truth's first differences along
time. A smoothing tracker whose output changes less than the talker's direction pays for it; a
tracker whose output follows the path at a constant delay pays little (its differences match
after a delay), so the term weighs responsiveness and jitter, not the delay itself.
"""
from __future__ import annotations

import torch


def frame_difference_mse(estimate: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """MSE between the first differences along time of ``estimate`` and ``truth``, both
    ``(batch, frames, 3)``; a scalar (0 for fewer than two frames)."""
    if estimate.shape[1] < 2:
        return estimate.new_zeros(())
    return torch.nn.functional.mse_loss(estimate.diff(dim=1), truth.diff(dim=1))


def tracking_loss(estimate: torch.Tensor, truth: torch.Tensor, delta_weight: float = 0.0) -> torch.Tensor:
    """The training loss of ``estimate`` against ``truth``, both ``(batch, frames, 3)``: the paper's
    MSE plus ``delta_weight`` times :func:`frame_difference_mse` (0: the paper's loss alone)."""
    loss = torch.nn.functional.mse_loss(estimate, truth)
    if delta_weight:
        loss = loss + delta_weight * frame_difference_mse(estimate, truth)
    return loss


def describe_loss(delta_weight: float = 0.0) -> str:
    """The loss in words, as exported weights and model cards record it."""
    paper = "MSE between the output and the true unit vector of every frame"
    if not delta_weight:
        return paper
    return f"{paper}, plus {delta_weight:g} x the MSE of their frame-to-frame differences"
