"""Frame-by-frame inference for the causal models.

:class:`StreamingRunner` holds a model's streaming state (per causal convolution, the last
``(kernel - 1) * dilation`` input frames of that layer) so each new frame costs the same whatever
the episode length, and the outputs equal the full-sequence pass (tests/test_streaming.py)::

    runner = StreamingRunner(Cross3D(16, 32))
    for frame in frames:               # (batch, 3, 16, 32) each
        y = runner.step(frame)         # (batch, 3)
"""
from __future__ import annotations

import torch
from torch import nn

import doabench


class StreamingRunner:
    """Cached causal inference for a model with ``init_state`` and ``stream_step`` (see layers.py).

    Runs in ``torch.inference_mode`` with the model in eval mode. ``reset()`` starts a new stream.
    """

    def __init__(self, model: nn.Module) -> None:
        if not hasattr(model, "stream_step"):
            raise TypeError(f"{type(model).__name__} has no streaming mode (it is not causal)")
        self.model = model.eval()
        self.frames = 0
        self.state = model.init_state()

    def reset(self) -> None:
        self.state = self.model.init_state()
        self.frames = 0

    def step(self, x_t: torch.Tensor) -> torch.Tensor:
        """One frame ``(batch, *frame_shape)`` -> ``(batch, 3)``, computed on the calling thread.

        One frame is some twenty small kernels. On an idle 2-core machine two torch threads made
        them 1.2-1.6x faster (Cross3D 4x8 / 16x32 / 32x64: 0.49 / 2.37 / 5.40 ms per frame
        against 0.58 / 3.86 / 8.12 ms with one), but with the other core busy (a training run,
        another process) every parallel kernel waits for a descheduled thread: a sim-grid episode of
        `doabench run --tracker cross3d:4x8` took 16.8 s with two threads and 1.4 s with one. One
        thread bounds the worst case at a few ms per 192 ms frame.
        """
        with doabench.single_threaded(), torch.inference_mode():
            y, self.state = self.model.stream_step(x_t, self.state)
        self.frames += 1
        return y

    def cached_frames(self) -> int:
        """Frames held in the caches, over all layers (constant once the stream has started)."""
        return sum(0 if s is None else int(s.shape[2]) for s in self.state)


#: frames per forward pass in :func:`stream_episode`: bounds memory on long episodes
EPISODE_CHUNK = 64


def stream_episode(model: nn.Module, x: torch.Tensor, chunk: int = EPISODE_CHUNK) -> torch.Tensor:
    """A causal model over a whole episode ``x`` (time on axis 2) in chunks of ``chunk`` frames,
    carrying the streaming state across them: ``(batch, frames, 3)``, equal to the one-pass output."""
    with torch.inference_mode():
        state, parts = model.init_state(), []
        for part in torch.split(x, chunk, dim=2):
            y, state = model.stream_chunk(part, state)
            parts.append(y)
    return torch.cat(parts, dim=1)
