"""Parsers of LOCATA's text tables: time stamps, poses, required times and VAD.

Format relied on (LOCATA documentation and the public readers cited in docs/locata.md):

* every table is tab-separated with one header line; time columns are ``year month day hour
  minute second`` (``second`` with a fractional part), local time without a time zone;
* ``position_array_<array>.txt``: time columns, ``x y z`` (reference point, world frame, metres),
  ``ref_vec_x/y/z``, ``rotation_11 .. rotation_33`` (``rotation_ij`` = row i, column j of the
  local-to-world rotation R) and, for arrays, ``mic1_x mic1_y mic1_z .. micN_z`` (world-frame
  microphone positions, in WAV channel order); ``position_source_<name>.txt`` the same without
  microphones;
* ``required_time.txt``: time columns and ``valid_flag`` (0/1);
* ``VAD_<array>_<name>.txt``: a ``VAD`` header and one 0/1 value per array-audio sample.

All clocks are converted to seconds relative to one origin (the first array-audio time stamp of
the recording) from calendar differences, so a recording that passes midnight stays monotonic.
Any separator made of whitespace is accepted (tabs in the official files).
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from doabench.errors import InputError
from doabench.locata.layout import require

TIME_COLUMNS = ("year", "month", "day", "hour", "minute", "second")
POSITION_COLUMNS = ("x", "y", "z")
REF_VEC_COLUMNS = ("ref_vec_x", "ref_vec_y", "ref_vec_z")
ROTATION_COLUMNS = tuple(f"rotation_{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3))
_MIC_RE = re.compile(r"^mic(\d+)_([xyz])$")


@dataclass(frozen=True)
class TimeOrigin:
    """A calendar instant: ``day`` (days since 1970-01-01) and ``second_of_day``."""

    day: int
    second_of_day: float

    def text(self) -> str:
        """ISO-like text, e.g. ``2017-09-20 15:40:25.068000`` (no time zone: the files have none)."""
        date = np.datetime64(int(self.day), "D")
        s = self.second_of_day
        h, rem = divmod(s, 3600.0)
        m, sec = divmod(rem, 60.0)
        return f"{date} {int(h):02d}:{int(m):02d}:{sec:09.6f}"


def read_table(path: Path, what: str, columns: tuple[str, ...] = ()) -> pd.DataFrame:
    """A LOCATA table with a header line; InputError naming the file if it cannot be parsed or
    lacks ``columns``, NotFoundError if it does not exist."""
    require(path, what)
    try:
        df = pd.read_csv(path, sep=r"\s+", engine="c")
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, ValueError) as exc:
        raise InputError(f"cannot parse LOCATA table {path} ({type(exc).__name__}: {str(exc).splitlines()[0]})") from None
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise InputError(f"LOCATA table {path} lacks column(s) {', '.join(missing)} (header: "
                         f"{' '.join(map(str, df.columns[:12]))}{' ...' if len(df.columns) > 12 else ''})")
    if len(df) == 0:
        raise InputError(f"LOCATA table {path} has a header but no rows")
    return df


def _numbers(df: pd.DataFrame, cols, path: Path) -> np.ndarray:
    """Columns as float64 ``(rows, len(cols))``; InputError naming the file on text values."""
    try:
        return df.loc[:, list(cols)].to_numpy(dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"LOCATA table {path}: non-numeric values in columns {', '.join(cols)}") from None


def calendar_parts(df: pd.DataFrame, path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``(day (rows,) int64 days since 1970-01-01, second_of_day (rows,) float64)``."""
    t = _numbers(df, TIME_COLUMNS, path)
    if not np.all(np.isfinite(t)):
        raise InputError(f"LOCATA table {path}: missing or non-finite time values")
    ymd = t[:, :3].astype(np.int64)
    try:
        # datetime64 arithmetic gives the day number of every row without a Python loop.
        days = (np.array(ymd[:, 0] - 1970, dtype="datetime64[Y]").astype("datetime64[M]")
                + (ymd[:, 1] - 1).astype("timedelta64[M]")).astype("datetime64[D]") + (ymd[:, 2] - 1).astype(
            "timedelta64[D]")
    except (ValueError, OverflowError):
        raise InputError(f"LOCATA table {path}: invalid calendar dates") from None
    bad = (ymd[:, 1] < 1) | (ymd[:, 1] > 12) | (ymd[:, 2] < 1) | (ymd[:, 2] > 31)
    if bad.any():
        raise InputError(f"LOCATA table {path}: invalid date on data row {int(np.argmax(bad)) + 1}")
    sod = t[:, 3] * 3600.0 + t[:, 4] * 60.0 + t[:, 5]
    return days.astype(np.int64), sod


def seconds_since(df: pd.DataFrame, path: Path, origin: TimeOrigin) -> np.ndarray:
    """Time stamps of ``df`` in seconds since ``origin``, ``(rows,)`` float64."""
    days, sod = calendar_parts(df, path)
    return (days - origin.day) * 86400.0 + (sod - origin.second_of_day)


def origin_of(df: pd.DataFrame, path: Path) -> TimeOrigin:
    """The first time stamp of ``df`` as a :class:`TimeOrigin`."""
    days, sod = calendar_parts(df.iloc[:1], path)
    return TimeOrigin(int(days[0]), float(sod[0]))


def check_increasing(t: np.ndarray, path: Path, strict: bool) -> None:
    """InputError naming ``path`` and the first offending data row unless ``t`` increases."""
    d = np.diff(t)
    bad = d <= 0 if strict else d < 0
    if bad.any():
        i = int(np.argmax(bad)) + 1
        kind = "strictly increasing" if strict else "in time order"
        raise InputError(f"LOCATA table {path}: time stamps are not {kind} (data row {i + 1}, line {i + 2}, "
                         f"goes from {t[i - 1]:.6f} s to {t[i]:.6f} s)")


def read_times(path: Path, what: str, origin: TimeOrigin | None = None) -> tuple[np.ndarray, TimeOrigin]:
    """A time-stamp table (audio time stamps): ``(seconds (rows,), origin)``; the origin is the
    first row when none is given. Audio clocks must be strictly increasing."""
    df = read_table(path, what, TIME_COLUMNS)
    origin = origin or origin_of(df, path)
    t = seconds_since(df, path, origin)
    check_increasing(t, path, strict=True)
    return t, origin


@dataclass
class Pose:
    """A pose table on its own clock.

    * ``times``: ``(P,)`` seconds since the recording's origin, nondecreasing without duplicates
    * ``position``: ``(P, 3)`` world-frame reference point, metres
    * ``rotation``: ``(P, 3, 3)`` local-to-world rotation R (array frame -> world: ``w = R v + p``)
    * ``mics``: ``(P, M, 3)`` world-frame microphone positions, or None (sources, or no columns)
    * ``dropped``: rows dropped for non-finite values or duplicate time stamps
    """

    times: np.ndarray
    position: np.ndarray
    rotation: np.ndarray
    mics: np.ndarray | None
    path: Path
    dropped: int = 0


def mic_columns(columns) -> list[str]:
    """``mic<k>_<x|y|z>`` columns in microphone order then x, y, z; InputError if incomplete."""
    found: dict[int, dict[str, str]] = {}
    for c in map(str, columns):
        m = _MIC_RE.match(c)
        if m:
            found.setdefault(int(m.group(1)), {})[m.group(2)] = c
    if not found:
        return []
    numbers = sorted(found)
    if numbers != list(range(1, len(numbers) + 1)) or any(len(found[k]) != 3 for k in numbers):
        raise InputError(f"microphone columns are incomplete: expected mic1_x .. mic{len(numbers)}_z, "
                         f"got {', '.join(c for c in map(str, columns) if _MIC_RE.match(c))}")
    return [found[k][a] for k in numbers for a in "xyz"]


def read_pose(path: Path, what: str, origin: TimeOrigin, with_mics: bool) -> Pose:
    """Parse a ``position_array_*`` / ``position_source_*`` file.

    Rows with non-finite geometry (tracking drop-outs) are dropped; time stamps must be in time
    order (InputError naming the file and row otherwise); of rows with equal time stamps the first
    is kept.
    """
    df = read_table(path, what, TIME_COLUMNS + POSITION_COLUMNS + ROTATION_COLUMNS)
    t = seconds_since(df, path, origin)
    check_increasing(t, path, strict=False)
    pos = _numbers(df, POSITION_COLUMNS, path)
    rot = _numbers(df, ROTATION_COLUMNS, path).reshape(-1, 3, 3)
    mics = None
    if with_mics:
        try:
            cols = mic_columns(df.columns)
        except InputError as exc:
            raise InputError(f"LOCATA table {path}: {exc}") from None
        if cols:
            mics = _numbers(df, cols, path).reshape(len(df), -1, 3)
    finite = np.all(np.isfinite(pos), 1) & np.all(np.isfinite(rot), (1, 2))
    if mics is not None:
        finite &= np.all(np.isfinite(mics), (1, 2))
    keep = finite.copy()
    keep[1:] &= np.diff(t) > 0  # duplicate time stamps: the first row of each run stays
    if not keep.any():
        raise InputError(f"LOCATA table {path}: no row with finite positions and rotations")
    return Pose(t[keep], pos[keep], rot[keep], None if mics is None else mics[keep], path, int((~keep).sum()))


def read_required_time(path: Path, origin: TimeOrigin) -> tuple[np.ndarray, np.ndarray]:
    """``required_time.txt``: ``(times (Q,) seconds, valid (Q,) bool)``, in time order."""
    df = read_table(path, "evaluation time stamps with valid_flag", TIME_COLUMNS + ("valid_flag",))
    t = seconds_since(df, path, origin)
    check_increasing(t, path, strict=False)
    flag = _numbers(df, ("valid_flag",), path)[:, 0]
    if not np.all(np.isin(flag, (0.0, 1.0))):
        raise InputError(f"LOCATA table {path}: valid_flag must be 0 or 1")
    return t, flag.astype(bool)


def read_vad(path: Path) -> np.ndarray:
    """``VAD_<array>_<name>.txt``: ``(n,)`` bool, one value per array-audio sample. A header line
    (``VAD``) is skipped when present."""
    require(path, "voice activity, one 0/1 per array sample")
    with open(path, "r") as f:
        first = f.readline().split()
    try:
        float(first[0])
        skip = 0
    except (ValueError, IndexError):
        skip = 1
    try:
        values = pd.read_csv(path, sep=r"\s+", header=None, skiprows=skip, usecols=[0],
                             dtype=np.float64).to_numpy()[:, 0]
    except (pd.errors.ParserError, pd.errors.EmptyDataError, ValueError) as exc:
        raise InputError(f"cannot parse LOCATA VAD file {path} ({type(exc).__name__})") from None
    if not np.all(np.isin(values, (0.0, 1.0))):
        raise InputError(f"LOCATA VAD file {path}: values must be 0 or 1")
    return values.astype(bool)
