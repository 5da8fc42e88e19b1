"""A run folder's human-readable record of its epochs: ``log.csv`` and ``loss.png``, both
rewritten atomically from the whole history after every epoch."""
from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any

from doabench.files import atomic_path, write_text

# The history row keys that log.csv shows, in order (rows hold more, e.g. the epoch's precision).
CSV_COLUMNS = ("epoch", "phase_snr", "batch_size", "lr", "train_loss", "val_loss", "val_rmsae_all",
               "val_rmsae_nonsilent", "val_rmsae_held", "n_cache", "trajectories_seen", "epoch_s", "compute_s",
               "trajectories_per_s")


def write_log(path: Path, history: list[dict[str, Any]]) -> None:
    """``history`` (one row per epoch) as CSV with the columns of :data:`CSV_COLUMNS`."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=CSV_COLUMNS, extrasaction="ignore")
    writer.writeheader()
    writer.writerows(history)
    write_text(path, buf.getvalue())


def plot_history(path: Path, history: list[dict[str, Any]], title: str) -> None:
    """Loss curves (train, validation) and validation RMSAE per epoch, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    epochs = [h["epoch"] for h in history]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    ax1.plot(epochs, [h["train_loss"] for h in history], label="train")
    ax1.plot(epochs, [h["val_loss"] for h in history], label="validation")
    ax1.set_xlabel("epoch")
    ax1.set_ylabel("MSE loss")
    ax1.set_yscale("log")
    ax1.legend()
    ax2.plot(epochs, [h["val_rmsae_all"] for h in history], label="all frames")
    ax2.plot(epochs, [h["val_rmsae_nonsilent"] for h in history], label="non-silent frames")
    held = [(h["epoch"], h["val_rmsae_held"]) for h in history if h.get("val_rmsae_held") is not None]
    if held:  # epochs validated since the hold rule was scored
        ax2.plot(*zip(*held), label="all frames, held in silences")
    ax2.set_xlabel("epoch")
    ax2.set_ylabel("validation RMSAE (deg)")
    ax2.legend()
    fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)
