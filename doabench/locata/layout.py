"""Where things are in a LOCATA corpus copy: the root, the recordings, the file names.

Official layout (dev and eval alike)::

    <root>/{dev,eval}/task{1..6}/recording{N}/{benchmark2,dicit,dummy,eigenmike}/
        audio_array_<array>.wav                 multichannel array audio, 48 kHz
        audio_array_timestamps_<array>.txt      one time stamp per array sample
        position_array_<array>.txt              array pose (+ microphone positions), ~120 Hz
        required_time.txt                       evaluation time stamps + valid_flag
        audio_source_<name>.wav                 source signal (dev; eval of the final release)
        audio_source_timestamps_<name>.txt      one time stamp per source sample
        position_source_<name>.txt              source position, same clock as the array pose
        VAD_<array>_<name>.txt                  voice activity, one 0/1 per array sample

The root comes from the ``locata_root`` option (``--locata-root``) or ``$DOABENCH_LOCATA``.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

from doabench.corpora.paths import LOCATA_ENV, corpus_root
from doabench.errors import ConfigError, NotFoundError

SPLITS = ("dev", "eval")
TASKS = (1, 2, 3, 4, 5, 6)
ARRAYS = ("benchmark2", "dicit", "dummy", "eigenmike")
_RECORDING_RE = re.compile(r"^recording(\d+)$")


def locata_root(root: str | os.PathLike | None = None) -> Path:
    """The corpus root: ``root`` if given, else ``$DOABENCH_LOCATA``; NotFoundError when neither
    names an existing folder."""
    text = corpus_root("locata", root)
    if not text:
        raise NotFoundError(
            "this task needs the LOCATA corpus (ODC-BY 1.0, DOI 10.5281/zenodo.3630471): pass "
            f"--locata-root PATH (Python: locata_root=PATH) or set {LOCATA_ENV} to the folder holding dev/ and eval/ (see docs/locata.md)")
    path = Path(text).expanduser()
    if not path.is_dir():
        raise NotFoundError(f"LOCATA root {path} does not exist (expected a folder holding dev/ and eval/)")
    return path


def check_choice(split: str, task: int, array: str) -> None:
    """ConfigError unless ``split``/``task``/``array`` are LOCATA names."""
    if split not in SPLITS:
        raise ConfigError(f"LOCATA split {split!r} is not one of {', '.join(SPLITS)}")
    if int(task) not in TASKS:
        raise ConfigError(f"LOCATA task {task!r} is not one of 1..6")
    if array not in ARRAYS:
        raise ConfigError(f"LOCATA array {array!r} is not one of {', '.join(ARRAYS)}")


@dataclass(frozen=True)
class Recording:
    """One recording folder ``<root>/<split>/task<T>/recording<N>/<array>/``."""

    root: Path
    split: str
    task: int
    number: int
    array: str

    @property
    def path(self) -> Path:
        return self.root / self.split / f"task{self.task}" / f"recording{self.number}" / self.array

    @property
    def id(self) -> str:
        return f"{self.split}/task{self.task}/recording{self.number}/{self.array}"

    # -- file names (documented in the module docstring) ------------------------------------------
    @property
    def audio_file(self) -> Path:
        return self.path / f"audio_array_{self.array}.wav"

    @property
    def audio_timestamps_file(self) -> Path:
        return self.path / f"audio_array_timestamps_{self.array}.txt"

    @property
    def array_position_file(self) -> Path:
        return self.path / f"position_array_{self.array}.txt"

    @property
    def required_time_file(self) -> Path:
        return self.path / "required_time.txt"

    def source_audio_file(self, name: str) -> Path:
        return self.path / f"audio_source_{name}.wav"

    def source_timestamps_file(self, name: str) -> Path:
        return self.path / f"audio_source_timestamps_{name}.txt"

    def source_position_file(self, name: str) -> Path:
        return self.path / f"position_source_{name}.txt"

    def vad_file(self, name: str) -> Path:
        return self.path / f"VAD_{self.array}_{name}.txt"

    def source_names(self) -> list[str]:
        """Source names, from ``position_source_<name>.txt`` (the ground truth) or, when there are
        none, from ``audio_source_<name>.wav``; sorted."""
        names = sorted(p.name[len("position_source_"):-len(".txt")] for p in self.path.glob("position_source_*.txt"))
        if not names:
            names = sorted(p.name[len("audio_source_"):-len(".wav")] for p in self.path.glob("audio_source_*.wav"))
        return names


def require(path: Path, what: str) -> Path:
    """``path`` if it is a file, else NotFoundError naming it and what it should hold."""
    if not path.is_file():
        raise NotFoundError(f"LOCATA file missing: {path} ({what})")
    return path


def find_recordings(root: str | os.PathLike | None, split: str, task: int, array: str) -> list[Recording]:
    """Recordings of ``split``/``task`` that have an ``<array>`` folder, by recording number.

    NotFoundError when the task folder does not exist or holds no such recording.
    """
    check_choice(split, task, array)
    base = locata_root(root)
    task_dir = base / split / f"task{int(task)}"
    if not task_dir.is_dir():
        raise NotFoundError(f"LOCATA folder {task_dir} does not exist (expected <root>/{split}/task{int(task)}/"
                            "recording<N>/...; is the root right?)")
    found = []
    for entry in task_dir.iterdir():
        m = _RECORDING_RE.match(entry.name)
        if m and (entry / array).is_dir():
            found.append(Recording(base, split, int(task), int(m.group(1)), array))
    if not found:
        raise NotFoundError(f"no LOCATA recordings with array {array!r} under {task_dir} "
                            f"(expected {task_dir}/recording<N>/{array}/)")
    return sorted(found, key=lambda r: r.number)
