"""The resume journal of a run: ``DIR/.<task>__<tracker>.partial.jsonl`` and its lock.

The first line is ``{"config": <hash of the run's configuration>}``; every later line is one
finished episode's record (as :func:`doabench.runner.loop.run_task` keeps it). A run started again
with the same configuration skips the journalled episodes; another configuration starts afresh.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
from pathlib import Path
from typing import Any, Iterator, Mapping

from doabench.errors import InputError
from doabench.files import append_line, exclusive_lock, to_json, write_text


def lock_path(partial_path: str | Path) -> Path:
    """The lock file of a run's resume journal."""
    p = Path(partial_path)
    return p.with_name(p.name.removesuffix(".partial.jsonl") + ".lock")


@contextlib.contextmanager
def run_lock(partial_path: str | Path) -> Iterator[None]:
    """Exclusive lock of the run writing ``partial_path`` (two runs with the same ``--out``, task
    and tracker would otherwise overwrite each other's journal and results): the second gets one
    line naming the first one's pid. The kernel releases it if the process dies; the lock file is
    removed when the run ends (:func:`doabench.files.exclusive_lock`)."""
    with exclusive_lock(lock_path(partial_path), f"{Path(partial_path).parent} for this task and tracker"):
        yield


def config_hash(config: Mapping[str, Any]) -> str:
    """The 16-hex-digit hash of a run's configuration that heads its journal."""
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()[:16]


def load_journal(path: str | Path | None, config_hash: str) -> dict[int, dict[str, Any]]:
    """Finished episodes of an interrupted run with the same configuration.

    The journal is rewritten with its valid lines only, so a line cut by a crash is dropped (that
    episode is redone) instead of having the next episode's line appended to the fragment. A
    header that is not doabench's is a one-line error: the file is left for the user to look at.
    """
    if not path:
        return {}
    path = Path(path)
    done: dict[int, dict[str, Any]] = {}
    keep: list[str] = []
    if path.exists():
        try:
            lines = path.read_text().splitlines()
            header = json.loads(lines[0]) if lines else {}
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            header = None
        if not isinstance(header, dict) or (lines and not isinstance(header.get("config"), str)):
            raise InputError(f"resume journal {path} is not a doabench run journal (bad first line); delete it "
                             "to start the run afresh")
        if header.get("config") == config_hash:
            for line in lines[1:]:
                try:
                    rec = json.loads(line)
                    index = int(rec["row"]["episode"])
                    if not isinstance(rec.get("errors"), list):
                        raise TypeError
                except (json.JSONDecodeError, KeyError, TypeError, ValueError):
                    continue  # a line cut by a crash: that episode is redone
                done[index] = rec
                keep.append(line)
    write_text(path, "".join(line + "\n" for line in [json.dumps({"config": config_hash})] + keep))
    return done


def append_record(path: str | Path, record: dict[str, Any]) -> None:
    """Journal one finished episode (a JSON-ready record) as one line; on a full disk the line is
    cut off again and the error names the journal, which stays resumable."""
    append_line(path, to_json(record, indent=None))


def journal_count(path: str | Path) -> int:
    """The finished episodes a journal holds (0 when there is none): for the stop message."""
    try:
        return max(0, len(Path(path).read_text().splitlines()) - 1)
    except OSError:
        return 0
