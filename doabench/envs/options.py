"""The run-time options of the built-in task kinds, as dataclasses (no heavy imports).

A kind's episode source declares its options as ``Options`` (:mod:`doabench.envs.sources`); the
built-in kinds' live here so that the command line builds its corpus flags from them
(:func:`doabench.cli.common.add_corpus_options`) without importing the sources (torch, h5py). A
field's metadata names its flag (``flag``), ``help``, ``choices`` and the flag's default
(``cli_default``); a field without a flag is a Python-only option.

Each kind's options also say which of them are part of a run's identity
(:meth:`SimulatedOptions.identity`): the options that change the episodes or their scoring (a
simulator, scene overrides, a LOCATA split or VAD), where they differ from the task's own, never
where a corpus lies. ``from_source`` reads them back from what a results file recorded of its
episode source (``task.source``), for files written before the identity was recorded.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping


@dataclass(frozen=True)
class SimulatedOptions:
    """The run-time options of a ``simulated`` task (``doabench run --librispeech ... --backend ...``,
    ``gymnasium.make(..., backend=...)``)."""

    librispeech: str | None = field(default=None, metadata={
        "flag": "--librispeech", "help": "LibriSpeech root (default: $DOABENCH_LIBRISPEECH)"})
    backend: str = field(default="builtin", metadata={
        "flag": "--backend", "cli_default": "builtin",
        "help": "room simulator: builtin, pyroomacoustics, pyroomacoustics-full, torchrir, gpurir or a plug-in's"})
    device: str | None = field(default=None, metadata={"flag": "--device", "help": "cpu or cuda (default cpu)"})
    # scene-distribution fields replaced in every cell (e.g. {"duration_s": 3} for quick checks);
    # results record it, and it changes the episodes
    scene_overrides: dict[str, Any] | None = None

    def identity(self, params: Mapping[str, Any]) -> dict[str, Any]:
        """The options that change the episodes, where they differ from the task's (``params``: its
        spec's): a simulator other than the task's own (a task that names one, like
        ``sim-walk-pra``, is rendered by it, and ``builtin`` stands for it there), and any scene
        overrides. The speech corpus and its subset are the task's (its spec fixes them); the
        LibriSpeech root and the device are not part of it."""
        task_backend = str((params.get("simulator") or {}).get("backend") or "builtin").lower()
        backend = str(self.backend or "builtin").lower()
        out: dict[str, Any] = {}
        if backend not in ("builtin", task_backend):
            out["backend"] = backend
        if self.scene_overrides:
            out["scene_overrides"] = {str(k): self.scene_overrides[k] for k in sorted(self.scene_overrides)}
        return out

    @classmethod
    def from_source(cls, source: Mapping[str, Any]) -> "SimulatedOptions":
        """The identity-bearing options a results file's ``task.source`` records."""
        return cls(backend=str(source.get("simulator") or "builtin"),
                   scene_overrides=dict(source.get("scene_overrides") or {}) or None)

    @staticmethod
    def reproduce_flags(source: dict[str, Any]) -> list[str]:
        """The flags that re-create a run, from its results' ``task.source``: the LibriSpeech root
        as a placeholder where the task's speech is LibriSpeech, and a simulator other than the
        builtin one."""
        flags = []
        if (source.get("speech") or {}).get("corpus") == "librispeech":
            flags.append("--librispeech LIBRISPEECH_ROOT")
        if source.get("simulator") not in (None, "builtin"):
            flags.append(f"--backend {source['simulator']}")
        return flags


@dataclass(frozen=True)
class LocataOptions:
    """The run-time options of a ``locata`` task (``doabench run --locata-root ... --split ... --vad ...``)."""

    locata_root: str | None = field(default=None, metadata={
        "flag": "--locata-root", "help": "LOCATA corpus root (default: $DOABENCH_LOCATA)"})
    split: str | None = field(default=None, metadata={
        "flag": "--split", "choices": ("dev", "eval"), "help": "LOCATA split (default: the task's, dev)"})
    vad: str | None = field(default=None, metadata={
        "flag": "--vad", "choices": ("webrtc", "corpus"),
        "help": "LOCATA voice activity: webrtc (WebRTC VAD of the array audio, the paper's; the tasks' default) "
                "or corpus (the corpus VAD files); recorded in the results"})
    source: str | None = None  # a source name, for recordings with several

    def identity(self, params: Mapping[str, Any]) -> dict[str, Any]:
        """The options that change the episodes or their scoring, where they differ from the
        task's (``params``: its spec's): the split, the VAD the non-silent frames come from, and
        a chosen source. The corpus root is not part of it."""
        locata = params.get("locata") or {}
        out: dict[str, Any] = {}
        if self.split is not None and self.split != locata.get("split", "dev"):
            out["split"] = self.split
        if self.vad is not None and self.vad != locata.get("vad", "webrtc"):
            out["vad"] = self.vad
        if self.source is not None:
            out["source"] = self.source
        return out

    @classmethod
    def from_source(cls, source: Mapping[str, Any]) -> "LocataOptions":
        """The identity-bearing options a results file's ``task.source`` records."""
        return cls(split=source.get("split"), vad=source.get("vad"), source=source.get("source"))

    @staticmethod
    def reproduce_flags(source: dict[str, Any]) -> list[str]:
        """The flags that re-create a run, from its results' ``task.source``: the corpus root as a
        placeholder, a split other than dev and the corpus VAD where the run used it."""
        flags = ["--locata-root LOCATA_ROOT"]
        if source.get("split") not in (None, "dev"):
            flags.append(f"--split {source['split']}")
        if source.get("vad") not in (None, "webrtc"):
            flags.append(f"--vad {source['vad']}")
        return flags


@dataclass(frozen=True)
class DatasetOptions:
    """A ``dataset`` task takes no run-time option: the file holds everything."""

    def identity(self, params: Mapping[str, Any]) -> dict[str, Any]:
        return {}

    @classmethod
    def from_source(cls, source: Mapping[str, Any]) -> "DatasetOptions":
        return cls()

    @staticmethod
    def reproduce_flags(source: dict[str, Any]) -> list[str]:
        return []


#: The options whose flags the command line offers, in the order its help lists them.
BUILTIN_KIND_OPTIONS = (SimulatedOptions, LocataOptions)
