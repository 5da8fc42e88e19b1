"""Writing and reading one episode group (``/episodes/NNNNNN``) of a dataset file.

An :class:`EpisodeRecord` is what one episode stores: arrays keyed by their path inside the group,
scalar attributes and the metadata dict. :func:`write_episode` writes it with one chunk per
dataset (an episode is read whole, so one chunk means one read and one decompression per
dataset) and sets the ``complete`` attribute last, after a flush. :func:`write_part` writes one
episode as its own journal part file (``make-dataset``'s local workers and its Ray engine).
"""
from __future__ import annotations

import io
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from doabench.datasets.schema import EPISODES, SCENE_ATTR_UNITS, describe_dataset, dumps, episode_name
from doabench.files import atomic_path

# Arrays smaller than this many bytes are stored contiguous and uncompressed: filters cost more
# than they save on a few hundred bytes.
_MIN_CHUNKED_BYTES = 2048


@dataclass
class EpisodeRecord:
    """One episode's content: ``arrays`` {path in group: array}, ``attrs`` and ``metadata``."""

    index: int
    arrays: dict[str, np.ndarray]
    attrs: dict[str, Any] = field(default_factory=dict)
    metadata: dict[str, Any] = field(default_factory=dict)


def dataset_options(arr: np.ndarray, compression: str) -> dict[str, Any]:
    """h5py ``create_dataset`` options: one chunk per dataset, compressed (gzip 4 or lzf) + shuffle."""
    if compression == "none" or arr.nbytes < _MIN_CHUNKED_BYTES or arr.ndim == 0:
        return {}
    opts: dict[str, Any] = {"chunks": arr.shape, "shuffle": arr.dtype.itemsize > 1}
    if compression == "gzip":
        opts.update(compression="gzip", compression_opts=4)
    else:
        opts["compression"] = compression
    return opts


def scene_arrays(metadata: dict[str, Any]) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """The scene parameters of a simulated episode as arrays (``scene/...``) and scalar attrs."""
    scene = metadata.get("scene")
    if not isinstance(scene, dict):
        return {}, {}
    arrays: dict[str, np.ndarray] = {}
    attrs: dict[str, Any] = {}
    room = scene.get("room") or {}
    if "dims" in room:
        arrays["scene/room_dims"] = np.asarray(room["dims"], np.float64)
    if "abs_weights" in room:
        arrays["scene/abs_weights"] = np.asarray(room["abs_weights"], np.float64)
    if "t60" in room:
        attrs["t60"] = float(room["t60"])
    array = scene.get("array") or {}
    if "position" in array:
        arrays["scene/array_position"] = np.asarray(array["position"], np.float64)
    if "mic_positions" in array:
        arrays["scene/mic_positions"] = np.asarray(array["mic_positions"], np.float64)
    if "trajectory" in scene:
        arrays["scene/trajectory"] = np.asarray(scene["trajectory"], np.float64)
    for key in ("snr_db", "seed", "static", "duration_s", "fs"):
        if key in scene and scene[key] is not None:
            attrs[key] = scene[key]
    if array.get("name") is not None:
        attrs["array_name"] = str(array["name"])
    return arrays, attrs


def write_episode(parent, record: EpisodeRecord, compression: str = "gzip"):
    """Write ``record`` as group ``parent/NNNNNN``; ``complete`` is set last, after a flush.

    A reader (or a resumed run) treats a group without ``complete = True`` as never written.
    """
    name = episode_name(record.index)
    if name in parent:
        del parent[name]
    g = parent.create_group(name)
    for path, arr in record.arrays.items():
        arr = np.asarray(arr)
        describe_dataset(g.create_dataset(path, data=arr, **dataset_options(arr, compression)), path)
    scene_data, scene_attrs = scene_arrays(record.metadata)
    for path, arr in scene_data.items():
        describe_dataset(g.create_dataset(path, data=arr), path)
    if scene_attrs:
        sg = g.require_group("scene")
        for k, v in scene_attrs.items():
            sg.attrs[k] = v
        sg.attrs["units"] = dumps({k: SCENE_ATTR_UNITS.get(k, "") for k in scene_attrs})
    # Metadata can exceed the 64 kB limit of an HDF5 attribute (long trajectories): a string dataset.
    describe_dataset(g.create_dataset("metadata", data=dumps(record.metadata)), "metadata")
    for k, v in record.attrs.items():
        g.attrs[k] = v
    g.attrs["index"] = int(record.index)
    g.file.flush()
    g.attrs["complete"] = True
    g.file.flush()
    return g


def is_complete(group) -> bool:
    return bool(group.attrs.get("complete", False))


def read_metadata(group) -> dict[str, Any]:
    raw = group["metadata"][()]
    return json.loads(raw.decode() if isinstance(raw, bytes) else raw)


def read_episode(group) -> EpisodeRecord:
    """Everything stored in an episode group (arrays loaded), the inverse of :func:`write_episode`."""
    arrays: dict[str, np.ndarray] = {}

    def visit(path, obj):
        if hasattr(obj, "dtype") and path != "metadata" and not path.startswith("scene/"):
            arrays[path] = obj[()]

    group.visititems(visit)
    attrs = {k: v for k, v in group.attrs.items() if k not in ("complete", "index")}
    return EpisodeRecord(int(group.attrs["index"]), arrays, attrs, read_metadata(group))


def write_part(folder: Path, record: EpisodeRecord, compression: str, tag: str = "") -> Path:
    """Write one episode into ``folder/NNNNNN.h5`` atomically (tmp file, fsync, rename); the part
    carries ``tag`` (:func:`~doabench.datasets.generate.part_tag` of the run's config) so a resume can check it."""
    import h5py

    name = episode_name(record.index)
    final = folder / f"{name}.h5"
    # Built in memory, then written by Python: the HDF5 library crashes the process when the disk
    # fills under it, while a Python write fails with an error the journal survives.
    buffer = io.BytesIO()
    with h5py.File(buffer, "w") as f:
        f.attrs["part_config"] = tag
        write_episode(f.create_group(EPISODES), record, compression)
    with atomic_path(final, tmp=folder / f".{name}.{os.getpid()}.tmp") as tmp:
        tmp.write_bytes(buffer.getbuffer())
    return final
