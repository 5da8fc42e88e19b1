"""The dataset file format ``doabench.dataset/1``: names, feature requests and safe opening.

Layout (full description with shapes and dtypes in docs/hdf5-schema.md)::

    /                               attrs: doabench_schema, task_id, task_version, config (JSON), ...
    /episodes/000123/               attrs: complete, index, seed, n_frames, n_samples
        features/srp_16x32          (T, 16, 32)  float32 or float16
        features/srp_max_16x32      (T, 2)       float32
        features/gcc                (T, P, lags) float32 or float16
        features/spectrogram        (T, 2M, K/2) float32 or float16
        audio                       (M, L)       float32          (feature "audio")
        sample_vad                  (L,)         bool             (with audio or --sample-vad)
        sample_directions           (L, 3)       float32          (with audio)
        truth/directions            (T, 3)       float64 unit vectors
        truth/elevation, azimuth    (T,)         float64 radians
        truth/times                 (T,)         float64 seconds (window centres)
        vad                         (T,)         bool
        scene/...                   room_dims, array_position, trajectory, ... (simulated tasks)
        metadata                    JSON string: the episode's full metadata

Every dataset but a plug-in's feature also carries ``units``, ``axes`` and ``description``
attributes (:data:`DATASET_ATTRS`).
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Sequence

from doabench.errors import ConfigError, InputError, NotFoundError
from doabench.features.kinds import (
    DATASET_KINDS,
    FEATURE_KINDS,
    FEATURES_GROUP,
    OBSERVATION_KINDS,
    FeatureKind,
    feature_kind,
    item_name,
    storage_path,
)

SCHEMA = "doabench.dataset/1"
SCHEMA_PREFIX = "doabench.dataset/"
EPISODES = "episodes"
FEATURES = FEATURES_GROUP
TRUTH_KEYS = ("directions", "elevation", "azimuth", "times")
DEFAULT_FEATURES = "srp:16x32"
COMPRESSIONS = ("gzip", "lzf", "none")


# What each dataset of an episode group holds, stored as its attributes ``units`` ("1":
# dimensionless), ``axes`` (the axes of its shape, in order) and ``description`` (docs/hdf5-schema.md
# lists them). Keys are paths inside an episode group; a map's grid suffix (features/srp_16x32) is
# looked up without it. Angles are radians here; CSV columns and results JSON use degrees and say so.
_FRAMES = "frames of the task's window and hop (root attribute frames)"
DATASET_ATTRS: dict[str, dict[str, str]] = {
    "features/srp": {"units": "1", "axes": "(frame, elevation, azimuth)",
                     "description": "SRP-PHAT map per frame on the equiangular grid (elevation rows over [0, pi], or "
                                    "[0, pi/2] for a planar array, ends included; azimuth columns -pi + 2 pi j / "
                                    "columns), mean removed and divided by its maximum; zero in silent frames"},
    "features/srp_max": {"units": "1", "axes": "(frame, [elevation, azimuth])",
                         "description": "where each SRP-PHAT map has its maximum, as fractions of the grid span: "
                                        "elevation row / (rows - 1), azimuth (phi + pi) / (2 pi); zero in silent "
                                        "frames. Two grid coordinates per frame, not the three components of "
                                        "truth/directions"},
    "features/gcc": {"units": "1", "axes": "(frame, microphone pair, lag)",
                     "description": "GCC-PHAT of every microphone pair (the array's pair order), lags -max_lag.."
                                    "max_lag samples; zero in silent frames"},
    "features/spectrogram": {"units": "1", "axes": "(frame, channel, frequency bin)",
                             "description": "channels 0..M-1: each microphone's magnitude divided by its maximum "
                                            "over frequency; M..2M-1: phase / pi; the DC bin dropped; zero in "
                                            "silent frames"},
    "features/spectrogram_ipd": {"units": "1", "axes": "(frame, channel, frequency bin)",
                                 "description": "channels 0..M-1 as in features/spectrogram; M..2M-1: each "
                                                "microphone's phase minus the first microphone's, wrapped, / pi "
                                                "(channel M is zero); the DC bin dropped; zero in silent frames"},
    "audio": {"units": "1", "axes": "(microphone, sample)",
              "description": "the microphone signals as simulated or recorded (linear amplitude, float32)"},
    "sample_directions": {"units": "1", "axes": "(sample, [x, y, z])",
                          "description": "truth per sample: unit vector from the array centre to the source, array "
                                         "frame"},
    "sample_vad": {"units": "1", "axes": "(sample,)", "description": "voice activity per sample"},
    "array_positions": {"units": "m", "axes": "(microphone, [x, y, z])",
                        "description": "this episode's microphone positions, array frame"},
    "truth/directions": {"units": "1", "axes": "(frame, [x, y, z])",
                         "description": f"truth per frame ({_FRAMES}): the mean of the window's per-sample "
                                        "directions, renormalised; unit vector from the array centre to the "
                                        "source, array frame"},
    "truth/elevation": {"units": "rad", "axes": "(frame,)",
                        "description": "polar angle of truth/directions from the array's +z axis (the zenith), in "
                                       "[0, pi]"},
    "truth/azimuth": {"units": "rad", "axes": "(frame,)",
                      "description": "atan2(y, x) of truth/directions, in [-pi, pi]"},
    "truth/times": {"units": "s", "axes": "(frame,)", "description": "the frames' window centres"},
    "vad": {"units": "1", "axes": "(frame,)",
            "description": "voice activity per frame: more than 2/3 of the window's samples active"},
    "scene/room_dims": {"units": "m", "axes": "([x, y, z],)", "description": "the shoebox room's size"},
    "scene/abs_weights": {"units": "1", "axes": "([x0, x1, y0, y1, z0, z1],)",
                          "description": "relative absorption of the six walls (the T60 sets their scale)"},
    "scene/array_position": {"units": "m", "axes": "([x, y, z],)",
                             "description": "array centre, room coordinates (at the first trajectory point for a "
                                            "moving array)"},
    "scene/mic_positions": {"units": "m", "axes": "(microphone, [x, y, z])",
                            "description": "the microphones, array frame"},
    "scene/trajectory": {"units": "m", "axes": "(trajectory point, [x, y, z])",
                         "description": "source positions, room coordinates: point i sounds during segment i of "
                                        "the signal cut into as many equal segments as there are points (the "
                                        "simulator's time grid, e.g. 156 points per 20 s), so their count differs "
                                        "from the frames'; truth/directions averages the resulting per-sample "
                                        "directions over each window"},
    "metadata": {"units": "", "axes": "()", "description": "JSON: the episode's full metadata"},
    "requested": {"units": "1", "axes": "(episode,)", "description": "the task episode indices this file is "
                                                                     "meant to hold"},
}
#: Units of the scalar attributes of an episode's ``scene`` group (stored as its ``units`` attribute, JSON).
SCENE_ATTR_UNITS = {"t60": "s", "snr_db": "dB", "duration_s": "s", "fs": "Hz", "seed": "", "static": "",
                    "array_name": ""}
_GRID_SUFFIX = re.compile(r"_\d+x\d+$")


def dataset_attrs(path: str) -> dict[str, str]:
    """``units``, ``axes`` and ``description`` of the dataset at ``path`` in an episode group
    (or ``requested`` at the root); empty for a path the schema does not describe (a plug-in's feature)."""
    return dict(DATASET_ATTRS.get(_GRID_SUFFIX.sub("", path), {}))


def describe_dataset(dataset, path: str) -> None:
    """Write :func:`dataset_attrs` onto an h5py ``dataset`` (the stored numbers are untouched)."""
    for key, value in dataset_attrs(path).items():
        dataset.attrs[key] = value


def episode_name(index: int) -> str:
    """Group name of episode ``index`` (zero-padded so that names sort like indices)."""
    return f"{int(index):06d}"


@dataclass(frozen=True)
class FeatureRequest:
    """One requested feature: ``kind`` (srp, gcc, spectrogram, audio or a plug-in's) and, for srp,
    ``resolution``."""

    kind: str
    resolution: tuple[int, int] | None = None

    @property
    def name(self) -> str:
        """Canonical text form: ``srp:16x32``, ``gcc``, ``spectrogram``, ``audio``."""
        return item_name(self.kind, self.resolution)

    @property
    def framed(self) -> bool:
        """Whether it stores the recording itself (a framed kind: ``audio``), not computed features."""
        return feature_kind(self.kind).framed

    def stored(self) -> dict[str, str]:
        """Item name -> path inside an episode group of everything this request stores (a kind and
        the kinds it comes with: an srp map with its maximum)."""
        kinds = (self.kind, *feature_kind(self.kind).comes_with)
        return {name: storage_path(name) for name in (item_name(k, self.resolution) for k in kinds)}


def stores_recording(item: str) -> bool:
    """Whether the stored item ``item`` is the recording itself (a framed kind's: ``audio``); False
    for computed features and for kinds not registered here."""
    found = FEATURE_KINDS.find(str(item).partition(":")[0])
    return found is not None and found[1].framed


_RES = re.compile(r"^(\d+)x(\d+)$")


def requestable_kind(name: str) -> FeatureKind | None:
    """The registered kind ``make-dataset --features`` may ask for by ``name`` (a built-in's name in
    any case, a plug-in's as registered), else None."""
    builtin = name.lower()
    found = FEATURE_KINDS.find(builtin if builtin in DATASET_KINDS else name)
    return found[1] if found is not None and found[1].requestable else None


def _request_order(request: FeatureRequest) -> tuple[int, str, tuple[int, int]]:
    """The files' canonical order: the built-ins' (srp by resolution, gcc, spectrogram, audio), then
    plug-in kinds by name."""
    rank = DATASET_KINDS.index(request.kind) if request.kind in DATASET_KINDS else len(DATASET_KINDS)
    return rank, request.kind, request.resolution or (0, 0)


def parse_feature(text: str) -> FeatureRequest:
    """``"srp:16x32"`` / ``"srp"`` (16x32) / ``"gcc"`` / ``"spectrogram"`` / ``"audio"`` / a plug-in kind."""
    name, _, res = text.strip().partition(":")
    found = requestable_kind(name.strip())
    if found is None:
        builtins = [f"{k}:NxM" if FEATURE_KINDS.get(k).on_grid else k for k in DATASET_KINDS]
        plugins = [k for k in FEATURE_KINDS.names() if k not in OBSERVATION_KINDS]
        raise ConfigError(f"unknown dataset feature {text!r}; choose from {', '.join(builtins + plugins)}")
    kind = found.name
    if not found.on_grid:
        if res:
            raise ConfigError(f"feature {kind!r} takes no resolution, got {text!r}")
        return FeatureRequest(kind)
    m = _RES.match(res.strip() or "16x32")
    if not m or int(m.group(1)) < 1 or int(m.group(2)) < 1:
        raise ConfigError(f"bad {kind} resolution in {text!r}; write it as {kind}:16x32 (elevations x azimuths)")
    return FeatureRequest(kind, (int(m.group(1)), int(m.group(2))))


def parse_features(spec: str | Iterable[str]) -> tuple[FeatureRequest, ...]:
    """A comma-separated list (or a sequence) of features, de-duplicated, in a canonical order.

    The order (srp by resolution, then gcc, spectrogram, audio, then plug-in kinds by name) makes
    ``srp:16x32,gcc`` and ``gcc,srp:16x32`` the same generation config.
    """
    items = spec.split(",") if isinstance(spec, str) else list(spec)
    requests = {parse_feature(t) for t in items if str(t).strip()}
    if not requests:
        raise ConfigError("no dataset feature requested; e.g. --features srp:16x32,gcc")
    return tuple(sorted(requests, key=_request_order))


def shard_indices(n_episodes: int, shard: tuple[int, int] | None) -> list[int]:
    """Episode indices of shard ``(k, n)`` (1-based k) of ``range(n_episodes)``: ``i % n == k - 1``.

    Strided rather than contiguous so that every shard gets its share of each grid cell.
    """
    return shard_of(range(n_episodes), shard)


def shard_of(indices: Sequence[int], shard: tuple[int, int] | None) -> list[int]:
    """Shard ``(k, n)`` (1-based k) of the episode ``indices`` a dataset takes: those at positions
    ``p % n == k - 1`` (strided, so that every shard gets its share of each grid cell)."""
    if shard is None:
        return list(indices)
    k, n = shard
    return list(indices)[k - 1::n]


def parse_shard(text: str | None) -> tuple[int, int] | None:
    """``"2/8"`` -> ``(2, 8)``; None stays None."""
    if text is None:
        return None
    m = re.match(r"^\s*(\d+)\s*/\s*(\d+)\s*$", str(text))
    if not m or not 1 <= int(m.group(1)) <= int(m.group(2)):
        raise ConfigError(f"--shard must be K/N with 1 <= K <= N (e.g. 1/4), got {text!r}")
    return int(m.group(1)), int(m.group(2))


def _plain(obj: Any) -> Any:
    import numpy as np

    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.generic,)):
        return obj.item()
    return str(obj)  # paths, enums, anything else a source describes itself with


def dumps(obj: Any) -> str:
    """Canonical JSON (sorted keys) for attributes; numpy values become plain numbers."""
    return json.dumps(obj, sort_keys=True, default=_plain)


def loads_attr(value: Any, what: str, path: str | Path) -> Any:
    """Parse a JSON attribute, or an InputError naming the file."""
    if isinstance(value, bytes):
        value = value.decode()
    try:
        return json.loads(value)
    except (TypeError, ValueError):
        raise InputError(f"{path}: attribute {what} is not valid JSON (corrupt file?)") from None


def open_h5(path: str | Path, mode: str = "r", check_schema: bool = True):
    """Open a dataset file with h5py; a missing, foreign, truncated or newer file is a clear error.

    Uses h5py's default file locking, so a file being written by ``make-dataset`` cannot be
    opened for writing twice.
    """
    import h5py

    path = Path(path)
    if mode == "r" and not path.exists():
        raise NotFoundError(f"dataset file {path} does not exist")
    if mode == "r" and path.is_dir():
        raise InputError(f"{path} is a folder, not a dataset file")
    if mode == "r":
        with open(path, "rb") as f:
            head = f.read(8)
        if head != b"\x89HDF\r\n\x1a\n":
            # HDF5 may put the signature at 512, 1024, ... when a user block exists; h5py knows.
            if not h5py.is_hdf5(str(path)):
                raise InputError(f"{path} is not an HDF5 file (not a doabench dataset)")
    try:
        f = h5py.File(path, mode)
    except OSError as exc:
        reason = str(exc).split("(")[-1].rstrip(")") if "(" in str(exc) else str(exc)
        if "unable to lock" in str(exc).lower():
            raise InputError(f"{path} is open for writing by another process ({reason})") from None
        raise InputError(f"{path} cannot be read: truncated or corrupt HDF5 file ({reason})") from None
    if check_schema:
        try:
            check_file_schema(f, path)
        except Exception:
            f.close()
            raise
    return f


def check_file_schema(f, path: str | Path) -> None:
    schema = f.attrs.get("doabench_schema")
    if isinstance(schema, bytes):
        schema = schema.decode()
    if schema is None:
        raise InputError(f"{path} is an HDF5 file but not a doabench dataset (no doabench_schema attribute)")
    if schema != SCHEMA:
        if str(schema).startswith(SCHEMA_PREFIX):
            raise InputError(f"{path} has schema {schema}; this doabench reads {SCHEMA} (update doabench)")
        raise InputError(f"{path} has schema {schema!r}, not a doabench dataset ({SCHEMA})")
    if EPISODES not in f:
        raise InputError(f"{path}: no {EPISODES} group (truncated or corrupt dataset)")


def feature_names(requests: Sequence[FeatureRequest]) -> list[str]:
    """Every item name the requests store (srp requests also store their srp_max)."""
    return [name for r in requests for name in r.stored()]
