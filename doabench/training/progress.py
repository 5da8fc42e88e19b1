"""The per-epoch progress bar of ``doabench train``.

The bar counts a batch as soon as it is done and shows the running loss with that count.
(Iterating through ``tqdm(loader)`` does not: tqdm only stores the count when it redraws, every
``mininterval`` seconds, while ``set_postfix`` redraws at once with the stored count, so the bar
sat at 0/N while the loss moved.)
"""
from __future__ import annotations

import sys
from typing import Any, TextIO


class EpochProgress:
    """A bar over one epoch's batches: ``step(loss)`` after each batch, ``close()`` at the end (or
    use it as a context manager). ``enabled=False`` draws nothing. On a terminal it redraws at
    most every 0.5 s; written to a file or pipe (logs) every 60 s, and once at the end, where
    the final count and loss stay."""

    def __init__(self, total: int | None, desc: str, enabled: bool = True, file: TextIO | None = None,
                 mininterval: float | None = None) -> None:
        self.n = 0
        self.bar = None
        if not enabled:
            return
        from tqdm import tqdm

        stream = file if file is not None else sys.stderr
        tty = bool(getattr(stream, "isatty", lambda: False)())
        # leave=True: a log file keeps each epoch's final count and loss (the last draw)
        self.bar = tqdm(total=total, desc=desc, file=stream, leave=True, dynamic_ncols=True,
                        mininterval=mininterval if mininterval is not None else (0.5 if tty else 60.0))

    def step(self, loss: float | None = None) -> None:
        """One batch done; ``loss``: the running loss to show beside the count."""
        self.n += 1
        if self.bar is None:
            return
        if loss is not None:
            self.bar.set_postfix(loss=f"{loss:.4f}", refresh=False)  # drawn with the count, below
        self.bar.update(1)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()

    def __enter__(self) -> "EpochProgress":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def loader_length(loader: Any) -> int | None:
    """The number of batches of ``loader``, or None when it does not know (the bar then counts
    without a total)."""
    try:
        return len(loader)
    except TypeError:
        return None
