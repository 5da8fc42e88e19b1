"""How the console names a tracker's weights and words their headline figures: one wording for
``list weights``, ``describe``, ``export`` and ``track``'s plot title."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable, Mapping

#: why a task has no lag: words of the note its figures carry, the wording of a table cell, and
#: what that means. The notes are those of :func:`doabench.metrics.lag_from_curves` and the weights
#: catalog's "not measured" (a run older than the lag measurement), so each cell says which case it is.
LAG_REASONS: tuple[tuple[str, str, str], ...] = (
    ("not measured", "lag not measured", "the committed run predates the lag measurement"),
    ("static source", "no lag (still scenes)", "the talker does not move in the run's scenes"),
    ("not following", "no lag (not following)", "the estimates do not follow the talker"),
    ("no voice-active frame", "no lag (no speech)", "no voice-active frame after the first 2 s"),
)
#: a null lag whose figures do not say why (a catalog written before the notes)
NO_LAG = ("", "no lag", "no defined lag, reason not recorded")


def no_lag_reason(figures: Mapping[str, Any]) -> tuple[str, str, str] | None:
    """The entry of :data:`LAG_REASONS` (or :data:`NO_LAG`) of figures without a lag; None when they have one."""
    if figures.get("lag_s") is not None:
        return None
    note = str(figures.get("lag_note") or "")
    return next((reason for reason in LAG_REASONS if reason[0] in note), NO_LAG)


def lag_text(figures: Mapping[str, Any]) -> str:
    """``lag 0.25 s``, or why the figures have no lag (``lag not measured``, ``no lag (still scenes)``)."""
    reason = no_lag_reason(figures)
    return f"lag {float(figures['lag_s']):.2f} s" if reason is None else reason[1]


def figure_text(figures: Mapping[str, Any] | None) -> str:
    """One task's figures in a cell: ``11.37, lag 0.25 s``; ``-`` without a complete run."""
    if not figures:
        return "-"
    return f"{float(figures['rmsae_all']):.2f}, {lag_text(figures)}"


def lag_legend(all_figures: Iterable[Mapping[str, Any]]) -> str:
    """What the no-lag wordings of ``all_figures`` mean, for a table's footnote (empty when each has a lag)."""
    reasons = {no_lag_reason(f) for f in all_figures if f}
    return "; ".join(f"{cell}: {meaning}" for reason in (*LAG_REASONS, NO_LAG) if reason in reasons
                     for _, cell, meaning in [reason])


def weights_label(tracker: Mapping[str, Any]) -> str | None:
    """The weights a tracker runs (its ``describe()``), named for a title or a console line:
    ``weights moving-long`` (shipped, by name), ``weights my.safetensors (sha256 0123456789ab)``
    (another file), ``untrained (random weights)``; None for a tracker without learned weights."""
    digest = tracker.get("weights_hash")
    if not digest:
        return "untrained (random weights)" if tracker.get("trained") is False else None
    if tracker.get("weights_name"):
        return f"weights {tracker['weights_name']}"
    where = tracker.get("weights")
    file = Path(str(where)).name if where else "(a file)"
    return f"weights {file} (sha256 {str(digest)[:12]})"
