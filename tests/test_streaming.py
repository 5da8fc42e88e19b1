"""Streaming inference equals the full-sequence pass for every causal model."""
from __future__ import annotations

import pytest
import torch

from doabench_baselines.cnn1d import CausalCnn1d, max_cnn1d
from doabench_baselines.cnn2d import SpecCnn2d
from doabench_baselines.cross3d import Cross3D
from doabench_baselines.seldnet import Seldnet
from doabench_baselines.streaming import StreamingRunner

RTOL, ATOL = 1e-4, 2e-5  # float32: different conv algorithms for 1 vs many frames


def assert_close(actual, expected):
    # torch.testing.assert_close costs seconds of imports on first use; this is all we need.
    assert actual.shape == expected.shape
    err = (actual - expected).abs() - RTOL * expected.abs()
    assert float(err.max()) <= ATOL, f"max abs difference {float((actual - expected).abs().max()):.3g}"



def _streamed(model, x):
    """Feed x (batch, C, frames, ...) one frame at a time; returns (batch, frames, 3)."""
    runner = StreamingRunner(model)
    return torch.stack([runner.step(x[:, :, t]) for t in range(x.shape[2])], dim=1)


def _small_gcc_cnn1d():
    # gcc-cnn1d is CausalCnn1d(858); the code path is the same for any input width, and 858
    # inputs cost nothing extra per frame, so the real size is used.
    return CausalCnn1d(66 * 13)


CASES = [
    ("cross3d-4x8", lambda: Cross3D(4, 8), (2, 3, 40, 4, 8)),
    ("cross3d-8x16", lambda: Cross3D(8, 16), (1, 3, 42, 8, 16)),
    ("gcc-cnn1d", _small_gcc_cnn1d, (2, 858, 45)),
    ("max-cnn1d", max_cnn1d, (2, 2, 45)),
    # The real spec-cnn2d (24 x 2048 inputs) needs ~0.4 GMAC per frame; a narrower one with the
    # same layers and 5 poolings (1024 bins -> 1) keeps the test fast.
    ("spec-cnn2d", lambda: SpecCnn2d(in_channels=4, n_freq=1024, channels=8), (2, 4, 45, 1024)),
]


@pytest.mark.parametrize("name,make,shape", CASES, ids=[c[0] for c in CASES])
def test_streaming_equals_full_sequence(name, make, shape):
    torch.manual_seed(0)
    model = make().eval()
    assert shape[2] > model.receptive_field  # longer than the receptive field: caches roll over
    x = torch.randn(shape)
    with torch.no_grad():
        full = model(x)
    assert_close(_streamed(model, x), full)


def test_chunked_streaming_equals_full_sequence():
    torch.manual_seed(1)
    model = Cross3D(4, 8).eval()
    x = torch.randn(1, 3, 37, 4, 8)
    with torch.no_grad():
        full = model(x)
        state, parts = model.init_state(), []
        for chunk in torch.split(x, [1, 10, 3, 23], dim=2):
            y, state = model.stream_chunk(chunk, state)
            parts.append(y)
    assert_close(torch.cat(parts, dim=1), full)


def test_cache_size_is_constant_and_matches_the_layers():
    """Each causal conv keeps (kernel - 1) * dilation frames: no growth with the episode."""
    model = Cross3D(4, 8)  # L = 2: 1 + 2 * 2 convs of 4 frames, two 1D convs of 8 frames
    runner = StreamingRunner(model)
    sizes = []
    for _ in range(35):
        runner.step(torch.randn(1, 3, 4, 8))
        sizes.append(runner.cached_frames())
    assert set(sizes) == {5 * 4 + 2 * 8}
    runner.reset()
    assert runner.cached_frames() == 0 and runner.frames == 0


def test_reset_restarts_the_stream():
    torch.manual_seed(2)
    model = max_cnn1d()
    runner = StreamingRunner(model)
    x = torch.randn(1, 2, 6)
    first = torch.stack([runner.step(x[:, :, t]) for t in range(6)], 1)
    runner.reset()
    again = torch.stack([runner.step(x[:, :, t]) for t in range(6)], 1)
    assert_close(first, again)


def test_stream_step_does_not_modify_the_given_state():
    model = max_cnn1d()
    state = model.init_state()
    _, new = model.stream_step(torch.randn(1, 2), state)
    assert all(s is None for s in state) and all(s is not None for s in new)


def test_a_step_runs_on_one_thread_and_gives_the_callers_threads_back(monkeypatch):
    seen = []
    model = max_cnn1d()
    original = model.stream_step
    monkeypatch.setattr(model, "stream_step", lambda x, s: (seen.append(torch.get_num_threads()), original(x, s))[1])
    runner = StreamingRunner(model)
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        runner.step(torch.randn(1, 2))
        assert seen == [1] and torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


def test_offline_model_has_no_streaming_mode():
    with pytest.raises(TypeError):
        StreamingRunner(Seldnet())
