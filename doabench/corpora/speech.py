"""Speech sources: where the source signal of a simulated scene comes from.

A :class:`SpeechSource` draws a chunk of ``duration_s`` seconds with a numpy Generator and can
re-create exactly the same chunk later from the ``info`` dict it recorded (which is what a
:class:`~doabench.acoustics.scenes.Scene` stores), so scenes stay small and JSON-serialisable.

Every chunk is processed as in the paper: mean removed, WebRTC VAD (:mod:`doabench.corpora.vad`)
and silent samples set to zero; ``SpeechChunk.vad`` is the per-sample VAD.

* :class:`LibriSpeechSource` reads the official LibriSpeech layout
  ``LibriSpeech/<subset>/<speaker>/<chapter>/<speaker>-<chapter>-<utt>.flac`` (no transcripts
  needed). A chunk is a random chapter's consecutive utterances, joined without gaps, from a
  random start. When the chapter is shorter than the chunk, the chunk starts at the chapter's
  beginning and continues with the next chapters in sorted (speaker, chapter) order, wrapping
  around the subset, until it is long enough.
* :class:`EmbeddedSpeechSource` serves the short synthetic clips shipped in
  ``doabench/data/speech`` (see the README there): the clips in random order, repeated as needed,
  separated by random pauses, from a random start inside the first clip.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np
import soundfile as sf

from doabench.corpora.paths import LIBRISPEECH_ENV, corpus_root
from doabench.corpora.vad import clean_with_vad
from doabench.errors import ConfigError, InputError, NotFoundError
from doabench.resampling import resample

LIBRISPEECH_SUBSETS = (
    "dev-clean", "dev-other", "test-clean", "test-other",
    "train-clean-100", "train-clean-360", "train-other-500",
)
_UTT_RE = re.compile(r"^(\d+)-(\d+)-(\d+)\.flac$")


@dataclass
class SpeechChunk:
    """A processed source signal.

    * ``signal``: ``(L,)`` float32, mean removed, zero where the VAD says silent
    * ``vad``: ``(L,)`` bool per-sample voice activity
    * ``info``: JSON-serialisable description; ``source.load(info)`` re-creates the chunk
    """

    signal: np.ndarray
    vad: np.ndarray
    info: dict[str, Any] = field(default_factory=dict)


@runtime_checkable
class SpeechSource(Protocol):
    """What scenes need from a speech corpus."""

    name: str

    def sample(self, rng: np.random.Generator, duration_s: float, fs: int) -> SpeechChunk:
        """Draw a chunk of ``round(duration_s * fs)`` samples."""
        ...

    def load(self, info: dict[str, Any]) -> SpeechChunk:
        """Re-create the chunk described by ``info`` (as recorded by :meth:`sample`)."""
        ...


def _n_samples(duration_s: float, fs: int) -> int:
    if not np.isfinite(duration_s) or duration_s <= 0:
        raise ConfigError(f"speech duration must be a positive number of seconds, got {duration_s}")
    if int(fs) <= 0:
        raise ConfigError(f"sample rate must be positive, got {fs}")
    return int(round(duration_s * fs))


def _read_mono(path: Path, fs: int) -> np.ndarray:
    """A mono float64 signal at ``fs`` (channels averaged, resampled if needed)."""
    try:
        x, fs_file = sf.read(str(path), dtype="float64", always_2d=True)
    except (RuntimeError, sf.LibsndfileError) as exc:
        raise InputError(f"cannot read audio file {path}: {exc}") from None
    return resample(x.mean(axis=1), fs_file, fs)


def _finish(raw: np.ndarray, fs: int, info: dict[str, Any]) -> SpeechChunk:
    """Mean removal and VAD cleaning of a raw chunk ``(L,)`` (the paper's processing)."""
    raw = raw - raw.mean()
    signal, vad, mode = clean_with_vad(raw, fs)
    return SpeechChunk(signal, vad, {**info, "vad_mode": mode})


# --------------------------------------------------------------------------- LibriSpeech


def _looks_like_subset(path: Path) -> bool:
    """True when ``path`` holds ``<speaker>/<chapter>/*.flac`` (checked on the first speaker only)."""
    try:
        speaker = next((p for p in sorted(path.iterdir()) if p.is_dir() and p.name.isdigit()), None)
        if speaker is None:
            return False
        chapter = next((p for p in sorted(speaker.iterdir()) if p.is_dir() and p.name.isdigit()), None)
        return chapter is not None and any(chapter.glob("*.flac"))
    except OSError:
        return False


def _how_to_get(subset: str) -> str:
    return (f"get it with `doabench data download librispeech --subset {subset}` or from "
            "https://www.openslr.org/12, then pass its path or set DOABENCH_LIBRISPEECH")


def resolve_librispeech(root: str | os.PathLike | None, subset: str | None) -> tuple[Path, str]:
    """Find the folder of one LibriSpeech subset.

    ``root`` (or ``$DOABENCH_LIBRISPEECH`` when None) may be the subset folder itself, the
    ``LibriSpeech`` folder holding subsets, or the folder that contains ``LibriSpeech``. ``subset``
    None accepts a subset folder, or a LibriSpeech folder holding exactly one subset.
    Returns ``(subset folder, subset name)``; raises NotFoundError with download instructions.
    """
    wanted = subset or "test-clean"
    root = corpus_root("librispeech", root)
    if root is None:
        raise NotFoundError(f"no LibriSpeech path given and {LIBRISPEECH_ENV} is not set; {_how_to_get(wanted)}")
    base = Path(root).expanduser()
    if not base.is_dir():
        if base.exists():  # a file (a .tar.gz not yet unpacked, say), a FIFO, a device
            raise ConfigError(f"LibriSpeech path {base} is not a folder; {_how_to_get(wanted)}")
        raise NotFoundError(f"LibriSpeech path {base} does not exist; {_how_to_get(wanted)}")
    if subset is not None and subset not in LIBRISPEECH_SUBSETS and not _looks_like_subset(base / subset):
        raise ConfigError(f"unknown LibriSpeech subset {subset!r} (official: {', '.join(LIBRISPEECH_SUBSETS)})")
    candidates = [base, base / "LibriSpeech"]
    if subset is not None:
        for c in candidates:
            if (c / subset).is_dir() and _looks_like_subset(c / subset):
                return c / subset, subset
        if base.name == subset and _looks_like_subset(base):
            return base, subset
        raise NotFoundError(f"LibriSpeech subset {subset!r} not found under {base}; {_how_to_get(subset)}")
    if _looks_like_subset(base):
        return base, base.name
    for c in candidates:
        found = sorted(p.name for p in c.iterdir() if p.is_dir() and _looks_like_subset(p)) if c.is_dir() else []
        if len(found) == 1:
            return c / found[0], found[0]
        if len(found) > 1:
            raise ConfigError(f"{c} holds several LibriSpeech subsets ({', '.join(found)}); choose one with --subset")
    raise NotFoundError(f"no LibriSpeech audio (<speaker>/<chapter>/*.flac) under {base}; {_how_to_get(wanted)}")


class LibriSpeechSource:
    """Chapter-based chunks of one LibriSpeech subset (see the module docstring).

    ``root``: path as accepted by :func:`resolve_librispeech` (None: ``$DOABENCH_LIBRISPEECH``).
    ``info`` of a chunk: ``corpus``, ``subset``, ``speaker``, ``chapter`` (of the first chapter),
    ``files`` (paths relative to the subset folder, in order), ``start`` (sample offset into the
    concatenation of ``files``), ``length`` and ``fs``.
    """

    name = "librispeech"

    def __init__(self, root: str | os.PathLike | None = None, subset: str | None = None) -> None:
        self.root, self.subset = resolve_librispeech(root, subset)
        self._chapters: list[tuple[str, str]] | None = None

    def __repr__(self) -> str:
        return f"LibriSpeechSource({str(self.root)!r}, {self.subset!r})"

    @property
    def chapters(self) -> list[tuple[str, str]]:
        """Sorted ``(speaker, chapter)`` folder names holding at least one utterance."""
        if self._chapters is None:
            found = []
            for spk in sorted(p for p in self.root.iterdir() if p.is_dir() and p.name.isdigit()):
                for chap in sorted(p for p in spk.iterdir() if p.is_dir() and p.name.isdigit()):
                    found.append((spk.name, chap.name))
            if not found:
                raise NotFoundError(f"no LibriSpeech chapters in {self.root}; {_how_to_get(self.subset)}")
            self._chapters = found
        return self._chapters

    def _utterances(self, speaker: str, chapter: str) -> list[tuple[str, int, int]]:
        """``(relative path, frames, file fs)`` of a chapter's utterances in utterance order."""
        return _chapter_utterances(str(self.root), speaker, chapter)

    def sample(self, rng: np.random.Generator, duration_s: float, fs: int = 16000) -> SpeechChunk:
        length = _n_samples(duration_s, fs)
        chapters = self.chapters
        first = int(rng.integers(len(chapters)))
        files: list[str] = []
        total = 0  # in output samples
        for k in range(len(chapters) + 1):  # one full wrap at most, plus the first chapter again
            utts = self._utterances(*chapters[(first + k) % len(chapters)])
            files += [u[0] for u in utts]
            chapter_len = sum(_resampled_length(u[1], u[2], fs) for u in utts)
            if k == 0 and chapter_len >= length:
                start = int(rng.integers(0, chapter_len - length + 1))
                break
            total += chapter_len
            start = 0
            if total >= length:
                break
        else:
            raise InputError(f"LibriSpeech subset {self.root} holds less than {duration_s} s of speech")
        files, start = self._trim(files, start, length, fs)
        info = {"corpus": "librispeech", "subset": self.subset, "speaker": chapters[first][0],
                "chapter": chapters[first][1], "files": files, "start": start, "length": length, "fs": fs}
        return self.load(info)

    def _trim(self, files: list[str], start: int, length: int, fs: int) -> tuple[list[str], int]:
        """Keep only the files the chunk ``[start, start + length)`` touches; shift ``start``."""
        sizes = {}
        for rel in files:
            spk, chap, _ = rel.split("/")
            sizes.update({r: _resampled_length(n, sr, fs) for r, n, sr in self._utterances(spk, chap)})
        ends = np.cumsum([sizes[r] for r in files])
        begins = ends - np.array([sizes[r] for r in files])
        keep = (ends > start) & (begins < start + length)
        first = int(np.argmax(keep))
        return [r for r, k in zip(files, keep) if k], int(start - begins[first])

    def load(self, info: dict[str, Any]) -> SpeechChunk:
        try:
            files, start, length, fs = list(info["files"]), int(info["start"]), int(info["length"]), int(info["fs"])
        except (KeyError, TypeError, ValueError):
            raise ConfigError("LibriSpeech speech info needs 'files', 'start', 'length' and 'fs'") from None
        if info.get("subset", self.subset) != self.subset:
            raise ConfigError(f"scene speech comes from LibriSpeech {info['subset']!r}, source reads {self.subset!r}")
        pieces, have = [], 0
        for rel in files:  # read only up to the end of the chunk
            if have >= start + length:
                break
            path = self.root / rel
            if not path.is_file():
                raise NotFoundError(f"LibriSpeech file {path} is missing (the scene was drawn from another copy?)")
            x = _read_mono(path, fs)
            pieces.append(x)
            have += len(x)
        raw = np.concatenate(pieces)[start : start + length] if pieces else np.zeros(0)
        if len(raw) < length:
            raise InputError(f"LibriSpeech chunk needs {length} samples from {len(files)} files, found {len(raw)}")
        return _finish(raw, fs, dict(info))


def _resampled_length(n: int, fs_in: int, fs_out: int) -> int:
    """Length of :func:`doabench.resampling.resample`'s output for ``n`` input samples (resample_poly's rule)."""
    if fs_in == fs_out:
        return n
    from math import gcd

    g = gcd(fs_in, fs_out)
    return -(-n * (fs_out // g) // (fs_in // g))


@lru_cache(maxsize=4096)
def _chapter_utterances(root: str, speaker: str, chapter: str) -> list[tuple[str, int, int]]:
    folder = Path(root) / speaker / chapter
    out = []
    for p in sorted(folder.iterdir()):
        m = _UTT_RE.match(p.name)
        if m and m.group(1) == speaker and m.group(2) == chapter:
            info = sf.info(str(p))
            out.append((int(m.group(3)), f"{speaker}/{chapter}/{p.name}", int(info.frames), int(info.samplerate)))
    if not out:
        raise NotFoundError(f"LibriSpeech chapter folder {folder} holds no <speaker>-<chapter>-<utt>.flac files")
    return [(rel, n, sr) for _, rel, n, sr in sorted(out)]


# --------------------------------------------------------------------------- embedded clips

PAUSE_RANGE_S = (0.2, 0.8)


@lru_cache(maxsize=1)
def _embedded_clips() -> tuple[tuple[str, np.ndarray, int], ...]:
    folder = resources.files("doabench.data") / "speech"
    clips = []
    for entry in sorted(folder.iterdir(), key=lambda e: e.name):
        if entry.name.endswith(".flac"):
            with resources.as_file(entry) as path:
                x, fs = sf.read(str(path), dtype="float64", always_2d=True)
            clips.append((entry.name, x.mean(axis=1), int(fs)))
    if not clips:
        raise NotFoundError("the embedded speech clips (doabench/data/speech/*.flac) are missing from the install")
    return tuple(clips)


class EmbeddedSpeechSource:
    """The synthetic clips shipped with doabench (no corpus needed; see the module docstring).

    ``info`` of a chunk: ``corpus`` ("embedded"), ``clips`` (names in order), ``pauses`` (samples
    of silence after each clip), ``start`` (offset into the concatenation), ``length``, ``fs``.
    """

    name = "embedded"

    def __repr__(self) -> str:
        return "EmbeddedSpeechSource()"

    @property
    def clip_names(self) -> list[str]:
        return [c[0] for c in _embedded_clips()]

    def sample(self, rng: np.random.Generator, duration_s: float, fs: int = 16000) -> SpeechChunk:
        length = _n_samples(duration_s, fs)
        clips = _embedded_clips()
        lengths = {name: n.shape[0] * fs / cfs for name, n, cfs in clips}
        order: list[str] = []
        pauses: list[int] = []
        start = None
        total = 0.0
        while start is None or total < start + length:
            for i in rng.permutation(len(clips)):
                name = clips[int(i)][0]
                if start is None:  # a random start inside the first clip
                    start = int(rng.integers(0, max(1, int(lengths[name] * 0.5))))
                order.append(name)
                pauses.append(int(rng.uniform(*PAUSE_RANGE_S) * fs))
                total += lengths[name] + pauses[-1]
                if total >= start + length:
                    break
        info = {"corpus": "embedded", "clips": order, "pauses": pauses, "start": start, "length": length, "fs": fs}
        return self.load(info)

    def load(self, info: dict[str, Any]) -> SpeechChunk:
        try:
            order, pauses = list(info["clips"]), [int(p) for p in info["pauses"]]
            start, length, fs = int(info["start"]), int(info["length"]), int(info["fs"])
        except (KeyError, TypeError, ValueError):
            raise ConfigError("embedded speech info needs 'clips', 'pauses', 'start', 'length' and 'fs'") from None
        by_name = {name: (x, cfs) for name, x, cfs in _embedded_clips()}
        pieces = []
        for name, pause in zip(order, pauses):
            if name not in by_name:
                raise NotFoundError(f"embedded speech clip {name!r} does not exist (have {', '.join(sorted(by_name))})")
            x, cfs = by_name[name]
            pieces += [resample(x, cfs, fs), np.zeros(pause)]
        raw = np.concatenate(pieces)[start : start + length] if pieces else np.zeros(0)
        if len(raw) < length:
            raise ConfigError(f"embedded speech info describes {len(raw)} samples, needs {length}")
        return _finish(raw, fs, dict(info))


def get_speech_source(librispeech: str | os.PathLike | None = None, subset: str | None = None) -> SpeechSource:
    """LibriSpeech when a path is given or ``$DOABENCH_LIBRISPEECH`` is set
    (:func:`doabench.corpora.paths.corpus_root`), else the embedded clips."""
    root = corpus_root("librispeech", librispeech)
    if root is None:
        return EmbeddedSpeechSource()
    return LibriSpeechSource(root, subset)


def speech_source_for(info: dict[str, Any], librispeech: str | os.PathLike | None = None) -> SpeechSource:
    """The source that can ``load`` a recorded chunk ``info`` (by its ``corpus``)."""
    corpus = info.get("corpus")
    if corpus == "embedded":
        return EmbeddedSpeechSource()
    if corpus == "librispeech":
        return LibriSpeechSource(librispeech, info.get("subset"))
    raise ConfigError(f"unknown speech corpus {corpus!r} in scene (expected embedded or librispeech)")
