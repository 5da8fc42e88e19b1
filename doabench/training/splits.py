"""Held-out validation speakers: a deterministic share of a corpus' speakers never used in training.

Speakers are ordered by the SHA-256 of their id (a fixed pseudo-random order that does not depend
on the file system) and the first ``round(fraction * n)`` (at least one) are the validation
speakers. Training draws speech only from the others, validation only from those, so the two never
overlap. Only LibriSpeech has speakers; other speech sources are returned unchanged.
"""
from __future__ import annotations

import hashlib
from typing import Iterable

from doabench.corpora.speech import LibriSpeechSource
from doabench.errors import ConfigError

SPLITS = ("train", "val")


def _key(speaker: str) -> str:
    return hashlib.sha256(f"doabench-val-speaker:{speaker}".encode()).hexdigest()


def validation_speakers(speakers: Iterable[str], fraction: float = 0.1) -> set[str]:
    """The held-out speakers among ``speakers`` (ids as strings)."""
    unique = sorted(set(map(str, speakers)))
    if len(unique) < 2:
        raise ConfigError(f"a speaker split needs at least 2 speakers, got {len(unique)}")
    n = min(len(unique) - 1, max(1, round(fraction * len(unique))))
    return set(sorted(unique, key=_key)[:n])


class SplitLibriSpeechSource(LibriSpeechSource):
    """A :class:`LibriSpeechSource` restricted to the ``train`` or ``val`` speakers of its subset.

    Chunks that need more than one chapter continue with the next chapter *of the same split*.
    """

    def __init__(self, root, subset: str | None, split: str, fraction: float = 0.1) -> None:
        if split not in SPLITS:
            raise ConfigError(f"speaker split must be one of {', '.join(SPLITS)}, got {split!r}")
        super().__init__(root, subset)
        self.split, self.fraction = split, fraction
        self._split_chapters: list[tuple[str, str]] | None = None

    def __repr__(self) -> str:
        return f"SplitLibriSpeechSource({str(self.root)!r}, {self.subset!r}, {self.split!r})"

    @property
    def all_chapters(self) -> list[tuple[str, str]]:
        return LibriSpeechSource.chapters.fget(self)  # type: ignore[attr-defined]

    @property
    def speakers(self) -> set[str]:
        return {s for s, _ in self.chapters}

    @property
    def chapters(self) -> list[tuple[str, str]]:
        if self._split_chapters is None:
            every = self.all_chapters
            held_out = validation_speakers((s for s, _ in every), self.fraction)
            keep = (lambda s: s in held_out) if self.split == "val" else (lambda s: s not in held_out)
            self._split_chapters = [c for c in every if keep(c[0])]
        return self._split_chapters


def split_speech_source(source, split: str, fraction: float = 0.1):
    """``source`` restricted to a speaker split when it has speakers (LibriSpeech), else itself."""
    if isinstance(source, LibriSpeechSource):
        return SplitLibriSpeechSource(source.root, source.subset, split, fraction)
    return source
