"""The scores of one validation pass, from the network's outputs on the fixed validation set.

Scored as ``doabench run`` scores an episode (:func:`doabench.metrics.score_frames`: planar
folding, silent frames in the all-frames RMSAE only), pooled over every frame of the set, so the
log's numbers mean what the results' do. Beside the raw outputs the outputs held under the
tracker's hold rule (:func:`doabench.trackers.hold.held_frame_index`) are scored, the way
``doabench run`` will use the weights.
"""
from __future__ import annotations

import torch

from doabench.metrics import score_frames
from doabench.trackers.hold import held_frame_index


class ValidationScores:
    """Collects batches of outputs with :meth:`add`; :meth:`metrics` scores them all.

    ``hold_frames``: the tracker's hold (None: it never holds, and the held score is the raw
    one); ``planar``: the array is planar (estimate and truth mirror-folded)."""

    def __init__(self, hold_frames: int | None, planar: bool) -> None:
        self.hold_frames, self.planar = hold_frames, planar
        self.losses: list[torch.Tensor] = []
        self.outputs: list[torch.Tensor] = []
        self.held: list[torch.Tensor] = []
        self.truths: list[torch.Tensor] = []
        self.active: list[torch.Tensor] = []

    def add(self, outputs: torch.Tensor, truth: torch.Tensor, vad: torch.Tensor) -> None:
        """One batch on the CPU: ``outputs`` and ``truth`` ``(B, T, 3)`` float32, ``vad`` ``(B, T)`` bool."""
        self.losses.append(torch.nn.functional.mse_loss(outputs, truth, reduction="none").mean(-1).flatten())
        self.outputs.append(outputs.reshape(-1, 3))
        if self.hold_frames is not None:
            index = torch.from_numpy(held_frame_index(vad.numpy(), self.hold_frames))  # (B, T)
            self.held.append(torch.gather(outputs, 1, index[..., None].expand_as(outputs)).reshape(-1, 3))
        self.truths.append(truth.reshape(-1, 3))
        self.active.append(vad.flatten())

    def metrics(self) -> dict[str, float]:
        """``val_loss`` (the paper's MSE over every frame, without a recipe's frame-difference term, so
        that runs compare) and the pooled RMSAE in degrees of
        all frames, of voice-active frames and of all frames under the hold rule."""
        truth = torch.cat(self.truths).double().numpy()
        active = torch.cat(self.active).numpy().astype(bool)

        def scored(outputs: list[torch.Tensor]) -> dict[str, float]:
            return score_frames(torch.cat(outputs).double().numpy(), truth, active, planar=self.planar).summary()

        raw = scored(self.outputs)
        return {"val_loss": float(torch.cat(self.losses).mean()), "val_rmsae_all": raw["rmsae_all"],
                "val_rmsae_nonsilent": raw["rmsae_nonsilent"],
                "val_rmsae_held": scored(self.held)["rmsae_all"] if self.held else raw["rmsae_all"]}
