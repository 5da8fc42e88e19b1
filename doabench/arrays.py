"""Microphone arrays.

A :class:`MicArray` holds microphone positions ``(n_mics, 3)`` in metres in the array frame.
Built in: ``nao`` (alias ``benchmark2``), the 12-microphone NAO robot head of LOCATA.
Users load their own from JSON or YAML::

    {"name": "my-array", "planar": false,
     "positions": [[0.05, 0.0, 0.0], [-0.05, 0.0, 0.0], [0.0, 0.05, 0.0]]}

``positions`` is required (metres, array frame, one ``[x, y, z]`` per microphone); ``name``
defaults to the file stem; ``planar`` defaults to "all z equal" (:func:`is_planar`).
The format is documented in docs/arrays.md.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from doabench.errors import ConfigError, NotFoundError
from doabench.geometry import SPEED_OF_SOUND, fold_to_upper  # noqa: F401  (fold_to_upper: re-exported)

# LOCATA "benchmark2" array (NAO robot head), microphone positions in the array frame, metres,
# rounded to the millimetre. Source: H. W. Loellmann et al., "IEEE-AASP Challenge on Acoustic
# Source Localization and Tracking: Documentation of Final Release", 2020 (LOCATA documentation),
# as summarised in shared/reference/README.md. Exact per-recording positions are in each LOCATA
# recording's position_array_benchmark2.txt and are used by the LOCATA reader when present.
_NAO_POSITIONS = (
    (-0.028, 0.030, -0.040),
    (0.006, 0.057, 0.000),
    (0.022, 0.022, -0.046),
    (-0.055, -0.024, -0.025),
    (-0.031, 0.023, 0.042),
    (-0.032, 0.011, 0.046),
    (-0.025, -0.003, 0.051),
    (-0.036, -0.027, 0.038),
    (-0.035, -0.043, 0.025),
    (0.029, -0.048, -0.012),
    (0.034, -0.030, 0.037),
    (0.035, 0.025, 0.039),
)


#: The most microphones an array may have. Pair distances, pair lists and GCC tables grow with the
#: square of the count (20,000 microphones: 8.9 GiB of distances before any check); the largest
#: arrays built (MIT's LOUD, 1,020 microphones; 1,024-microphone acoustic cameras) fit.
MAX_MICS = 1024

#: The largest array file read (4 MiB): checked before the file is read.
MAX_ARRAY_FILE_BYTES = 4 << 20

PLANAR_TOLERANCE = 1e-3  # z spread allowed for "planar", as a fraction of the aperture


def is_planar(positions: np.ndarray) -> bool:
    """Whether every microphone lies in one plane z = const (within 0.1 % of the aperture)."""
    pos = np.asarray(positions, dtype=np.float64)
    aperture = float(np.linalg.norm(pos[:, None] - pos[None], axis=-1).max())
    return bool(np.ptp(pos[:, 2]) <= PLANAR_TOLERANCE * aperture)


@dataclass(frozen=True)
class MicArray:
    """A microphone array: positions ``(n_mics, 3)`` in metres in the array frame."""

    name: str
    positions: np.ndarray
    #: all microphones in one plane z = const of the array frame: SRP grids cover elevations
    #: 0-90 degrees and scoring folds truth and estimates onto the upper half-space (a planar
    #: array cannot tell a direction from its mirror image). None (the default): detected from
    #: the positions (:func:`is_planar`).
    planar: bool | None = None
    source: str = field(default="builtin", compare=False)

    def __post_init__(self) -> None:
        pos = np.asarray(self.positions, dtype=np.float64)
        where = f"array {self.name!r} ({self.source})"
        if pos.ndim != 2 or pos.shape[1] != 3:
            raise ConfigError(f"{where}: positions must be a list of [x, y, z], got shape {pos.shape}")
        if pos.shape[0] < 2:
            raise ConfigError(f"{where}: needs at least 2 microphones, got {pos.shape[0]}")
        if pos.shape[0] > MAX_MICS:
            raise ConfigError(f"{where}: {pos.shape[0]} microphones, more than the limit of {MAX_MICS}")
        if not np.all(np.isfinite(pos)):
            raise ConfigError(f"{where}: positions contain NaN or infinite values")
        d = np.linalg.norm(pos[:, None] - pos[None], axis=-1) + np.eye(len(pos))
        if np.any(d < 1e-6):
            i, j = np.argwhere(d < 1e-6)[0]
            raise ConfigError(f"{where}: microphones {i + 1} and {j + 1} are at the same place")
        pos.setflags(write=False)
        object.__setattr__(self, "positions", pos)
        object.__setattr__(self, "planar", is_planar(pos) if self.planar is None else bool(self.planar))

    @property
    def n_mics(self) -> int:
        return int(self.positions.shape[0])

    @property
    def pairs(self) -> np.ndarray:
        """Unique microphone pairs ``(n_pairs, 2)`` with i < j, in lexicographic order."""
        i, j = np.triu_indices(self.n_mics, 1)  # row by row: (0, 1), (0, 2), ..., (1, 2), ...
        return np.stack([i, j], axis=1).astype(np.int64)

    @property
    def max_distance(self) -> float:
        """Largest inter-microphone distance in metres."""
        p = self.positions
        return float(np.linalg.norm(p[:, None] - p[None], axis=-1).max())

    def max_lag(self, fs: int, c: float = SPEED_OF_SOUND) -> int:
        """GCC lags kept: ``ceil(d_max / c * fs)`` on each side."""
        return int(np.ceil(self.max_distance / c * fs))

    def with_positions(self, positions: np.ndarray, source: str) -> "MicArray":
        """Same array name and planarity with other (e.g. per-recording measured) positions."""
        return MicArray(self.name, np.asarray(positions, dtype=np.float64), self.planar, source)

    def to_dict(self) -> dict:
        return {"name": self.name, "planar": self.planar, "positions": self.positions.tolist()}


_BUILTIN = {"nao": lambda: MicArray("nao", np.array(_NAO_POSITIONS), planar=False)}
_ALIASES = {"benchmark2": "nao"}


def builtin_arrays() -> list[str]:
    """Names of the built-in arrays (aliases not included)."""
    return sorted(_BUILTIN)


def load_array_file(path: str | Path) -> MicArray:
    """Load an array from a JSON or YAML file (format in the module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise NotFoundError(f"array file {path} does not exist" if not path.exists() else
                            f"array file {path} is not a regular file")
    size = path.stat().st_size
    if size > MAX_ARRAY_FILE_BYTES:
        raise ConfigError(f"array file {path} holds {size} bytes, more than the limit of {MAX_ARRAY_FILE_BYTES} "
                          f"(an array of {MAX_MICS} microphones takes about 100 kB)")
    try:
        text = path.read_text()
        if path.suffix.lower() in (".yaml", ".yml"):
            import yaml

            data = yaml.safe_load(text)
        else:
            data = json.loads(text)
    except Exception as exc:  # any parse failure is the user's file
        raise ConfigError(f"array file {path}: cannot parse ({type(exc).__name__}: {exc})") from None
    return _array_from_mapping(data, path)


ARRAY_FILE_KEYS = ("name", "planar", "positions")


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _array_from_mapping(data, path: Path) -> MicArray:
    """Validate an array file's contents strictly: a wrong type or an unknown key names the file and
    the field (a string ``"false"`` is not a boolean, ``true`` is not a coordinate)."""
    if not isinstance(data, dict) or "positions" not in data:
        raise ConfigError(f"array file {path}: expected a mapping with a 'positions' list")
    unknown = sorted(str(k) for k in data if k not in ARRAY_FILE_KEYS)
    if unknown:
        raise ConfigError(f"array file {path}: unknown field(s) {', '.join(map(repr, unknown))}; "
                          f"expected {', '.join(ARRAY_FILE_KEYS)}")
    rows = data["positions"]
    if not isinstance(rows, list) or not rows:
        raise ConfigError(f"array file {path}: field 'positions' must be a non-empty list of [x, y, z]")
    if len(rows) > MAX_MICS:
        raise ConfigError(f"array file {path}: {len(rows)} microphones, more than the limit of {MAX_MICS}")
    for i, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != 3:
            raise ConfigError(f"array file {path}: field 'positions[{i}]' must be a list of [x, y, z], got {row!r}"
                              if isinstance(row, list) else
                              f"array file {path}: field 'positions[{i}]' must be [x, y, z], got {row!r}")
        for j, v in enumerate(row):
            if not _is_number(v):
                raise ConfigError(f"array file {path}: field 'positions[{i}][{j}]' must be a number (metres), "
                                  f"got {v!r}")
    pos = np.asarray(rows, dtype=np.float64)
    name = data.get("name", path.stem)
    if not isinstance(name, str) or not name.strip():
        raise ConfigError(f"array file {path}: field 'name' must be a non-empty string, got {name!r}")
    planar = data.get("planar")  # None: detected from the positions (MicArray.planar)
    if planar is not None and not isinstance(planar, bool):
        raise ConfigError(f"array file {path}: field 'planar' must be true or false, got {planar!r}")
    return MicArray(name, pos, planar, source=str(path))


def get_array(name_or_path: str | Path | MicArray) -> MicArray:
    """A built-in array by name (``nao``, ``benchmark2``) or one loaded from a JSON/YAML file."""
    if isinstance(name_or_path, MicArray):
        return name_or_path
    key = str(name_or_path)
    key = _ALIASES.get(key.lower(), key.lower())
    if key in _BUILTIN:
        return _BUILTIN[key]()
    p = Path(str(name_or_path))
    if p.suffix.lower() in (".json", ".yaml", ".yml") or p.exists():
        return load_array_file(p)
    raise NotFoundError(
        f"unknown array {name_or_path!r}: use one of {', '.join(builtin_arrays() + list(_ALIASES))} "
        "or a path to a JSON/YAML array file"
    )
