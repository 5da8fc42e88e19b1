"""``doabench dataset merge a.h5 b.h5 --out all.h5``: join shards of one dataset.

The inputs must come from the same task and generation config (shard and episode count aside).
An episode present in several inputs must be identical in all of them (then it is kept once);
otherwise the merge is refused. The output is written to ``<out>.partial`` and renamed, so a
killed merge leaves no half-written output.
"""
from __future__ import annotations

import datetime as _dt
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from doabench.datasets.generate import SHARD_KEYS, config_difference, describe_difference, partial_path
from doabench.datasets.layout import read_episode
from doabench.datasets.reader import DatasetFile
from doabench.datasets.schema import EPISODES, describe_dataset, dumps, episode_name
from doabench.errors import InputError
from doabench.files import atomic_path

MERGE_IGNORED = SHARD_KEYS + ("merged_from",)


def records_equal(a, b) -> bool:
    """Same arrays (bitwise, NaN == NaN), attributes and metadata."""
    if a.arrays.keys() != b.arrays.keys() or a.metadata != b.metadata:
        return False
    if a.attrs.keys() != b.attrs.keys() or any(np.any(a.attrs[k] != b.attrs[k]) for k in a.attrs):
        return False
    for k, x in a.arrays.items():
        y = b.arrays[k]
        if x.dtype != y.dtype or not np.array_equal(x, y, equal_nan=x.dtype.kind == "f"):
            return False
    return True


def verify_group(f: DatasetFile, index: int) -> None:
    """Read (and so decompress and checksum) every dataset of episode ``index``: merge copies raw
    chunks, so a corrupt chunk would otherwise be copied into the output unnoticed."""
    group = f.group(index)
    names: list[str] = []
    group.visititems(lambda path, obj: names.append(path) if hasattr(obj, "dtype") else None)
    for name in names:
        try:
            group[name][()]
        except (OSError, ValueError, KeyError) as exc:
            msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise InputError(f"{f.path}: episode {index}: {name} is corrupt ({msg}); it cannot be merged") from None


def merge_datasets(inputs: Sequence[str | Path], out: str | Path) -> dict[str, Any]:
    """Merge dataset files into ``out``; returns a summary (episodes, duplicates, requested)."""
    import h5py

    out = Path(out)
    paths = [Path(p) for p in inputs]
    if not paths:
        raise InputError("dataset merge needs at least one input file")
    if any(p.resolve() == out.resolve() for p in paths if out.exists()):
        raise InputError(f"--out {out} is also an input; write the merge to a new file")
    files = [DatasetFile(p) for p in paths]
    try:
        first = files[0]
        for f in files[1:]:
            diff = config_difference(first.config, f.config, ignore=MERGE_IGNORED)
            if diff:
                raise InputError(f"{f.path} is not a shard of the same dataset as {first.path} "
                                 f"({describe_difference(first.config, f.config, diff)})")
        owner: dict[int, DatasetFile] = {}
        duplicates = 0
        for f in files:
            for i in f.indices:
                if i in owner:
                    if not records_equal(_read(owner[i], i), _read(f, i)):
                        raise InputError(f"episode {i} differs between {owner[i].path} and {f.path}; "
                                         "they cannot be merged")
                    duplicates += 1
                else:
                    owner[i] = f
        requested = sorted(set().union(*(set(_requested(f)) for f in files)))
        config = dict(first.config, shard=None, episodes=max(int(f.config.get("episodes", 0)) for f in files))
        merged_from = [{"file": f.path.name, "shard": f.config.get("shard"), "episodes": f.config.get("episodes"),
                        "versions": f.attr_json("versions", {}), "created": f.file.attrs.get("created")}
                       for f in files]
        config["merged_from"] = [{k: m[k] for k in ("file", "shard", "episodes")} for m in merged_from]
        # At most the sources' size: reserved first (HDF5 crashes the process on a full disk).
        need = sum(f.path.stat().st_size for f in files if f in owner.values()) + (1 << 20)
        with atomic_path(out, tmp=partial_path(out), reserve=need) as tmp:
            with h5py.File(tmp, "w") as dst:
                for k, v in first.file.attrs.items():
                    dst.attrs[k] = v
                generation = first.attr_json("generation", {})
                generation["merged_from"] = merged_from
                dst.attrs.update({"config": dumps(config), "n_requested": len(requested),
                                  "generation": dumps(generation),
                                  "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")})
                describe_dataset(dst.create_dataset("requested", data=np.asarray(requested, np.int64)), "requested")
                eps = dst.create_group(EPISODES)
                for i in sorted(owner):
                    verify_group(owner[i], i)
                    src = owner[i].file[EPISODES]
                    src.copy(src[episode_name(i)], eps, name=episode_name(i))
        return {"path": str(out), "episodes": len(owner), "duplicates": duplicates, "requested": len(requested),
                "missing": sorted(set(requested) - set(owner))}
    finally:
        for f in files:
            f.close()


def _read(f: DatasetFile, index: int):
    try:
        return read_episode(f.group(index))
    except (OSError, ValueError) as exc:
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"{f.path}: episode {index} is corrupt ({msg}); it cannot be merged") from None


def _requested(f: DatasetFile) -> list[int]:
    if "requested" in f.file:
        return [int(i) for i in f.file["requested"][()]]
    return list(f.indices)
