"""Atomic file writing: a crash, Ctrl-C or power cut never leaves a half-written output behind.

:func:`atomic_path` is the one helper for every file doabench writes (results, leaderboards,
figures, checkpoints, caches, dataset parts and files, exports): write a temporary file in the
target's folder, fsync it, rename it over the target, fsync the folder."""
from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any, Iterator

import numpy as np


def current_umask() -> int:
    """The process umask (read without changing it where /proc allows, else set and restored)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def apply_umask(path: str | Path, folder: bool = False) -> None:
    """Give ``path`` the mode a plain ``open()``/``mkdir()`` would have: 0666 (0777 for a folder)
    less the umask. ``tempfile`` creates 0600 files and 0700 folders whatever the umask."""
    os.chmod(path, (0o777 if folder else 0o666) & ~current_umask())


def fsync_file(path: str | Path) -> None:
    """Flush ``path``'s content to the disk."""
    with open(path, "rb") as fh:
        os.fsync(fh.fileno())


def fsync_dir(folder: str | Path) -> None:
    """Flush ``folder``'s entries (a rename into it) to the disk, where the platform allows."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


@contextlib.contextmanager
def atomic_path(path: str | Path, suffix: str | None = None, tmp: str | Path | None = None) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; on success it is fsynced, replaces ``path``
    atomically and the folder is fsynced. The temporary file is a fresh ``.<name>.XXXX<suffix>``
    (mode as a plain ``open()`` gives), or ``tmp`` when the caller needs a name it recognises later
    (a stale one is removed first); it never outlives the block."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if tmp is None:
        fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix or path.suffix or ".tmp", dir=path.parent)
        os.close(fd)
        tmp_path = Path(name)
    else:
        tmp_path = Path(tmp)
        tmp_path.unlink(missing_ok=True)
    try:
        yield tmp_path
        if tmp_path.exists():
            if tmp is None:
                apply_umask(tmp_path)
            fsync_file(tmp_path)
        os.replace(tmp_path, path)
        fsync_dir(path.parent)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def _default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def to_json(obj: Any, indent: int | None = 2) -> str:
    return json.dumps(obj, indent=indent, default=_default, allow_nan=True)


def write_json(path: str | Path, obj: Any) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_text(to_json(obj) + "\n")
    return Path(path)


def write_text(path: str | Path, text: str) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)
