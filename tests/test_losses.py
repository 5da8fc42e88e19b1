"""The training losses: the paper's MSE, and the frame-difference term that weighs how an output
follows the truth's frame-to-frame change."""
from __future__ import annotations

import math

import pytest
import torch

from doabench.training.losses import frame_difference_mse, tracking_loss


def arc(frames: int, deg_per_frame: float, start_deg: float = 0.0) -> torch.Tensor:
    """Unit vectors ``(1, frames, 3)`` of a talker walking a horizontal arc round the array."""
    az = torch.deg2rad(start_deg + deg_per_frame * torch.arange(frames, dtype=torch.float64))
    return torch.stack([az.cos(), az.sin(), torch.zeros_like(az)], -1)[None]


def test_without_a_weight_the_loss_is_the_papers_mse():
    truth = arc(50, 3.0)
    estimate = truth + 0.1 * torch.randn(truth.shape, generator=torch.Generator().manual_seed(0), dtype=truth.dtype)
    assert tracking_loss(estimate, truth) == torch.nn.functional.mse_loss(estimate, truth)
    assert tracking_loss(estimate, truth, 0.0) == torch.nn.functional.mse_loss(estimate, truth)


def test_a_constant_offset_changes_as_the_truth_does_and_costs_no_difference_term():
    truth = arc(50, 3.0)
    offset = truth + torch.tensor([0.1, -0.2, 0.05], dtype=truth.dtype)
    assert frame_difference_mse(offset, truth) == pytest.approx(0.0, abs=1e-24)
    assert tracking_loss(offset, truth, 5.0) == pytest.approx(float(torch.nn.functional.mse_loss(offset, truth)))


def test_white_jitter_costs_twice_its_variance_and_a_frozen_output_the_truths_speed():
    truth = arc(20_000, 0.0)
    sigma = 0.05
    jitter = truth + sigma * torch.randn(truth.shape, generator=torch.Generator().manual_seed(1), dtype=truth.dtype)
    # differences of independent noise have twice its variance
    assert frame_difference_mse(jitter, truth) == pytest.approx(2 * sigma ** 2, rel=0.03)
    # an output that never moves misses the whole change: |d truth|^2 / 3 per coordinate,
    # with |d truth| = 2 sin(step / 2) on the unit circle
    step = math.radians(4.0)
    moving = arc(200, 4.0)
    frozen = moving[:, :1].expand_as(moving)
    assert frame_difference_mse(frozen, moving) == pytest.approx((2 * math.sin(step / 2)) ** 2 / 3, rel=1e-9)


def test_one_frame_has_no_difference_term():
    truth = arc(1, 3.0)
    assert frame_difference_mse(truth * 0.5, truth) == 0.0


def test_the_loss_is_described_as_weights_files_record_it():
    from doabench.training.losses import describe_loss

    assert describe_loss() == describe_loss(0.0) == "MSE between the output and the true unit vector of every frame"
    assert describe_loss(5.0).endswith("plus 5 x the MSE of their frame-to-frame differences")
