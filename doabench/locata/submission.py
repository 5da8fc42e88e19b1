"""The LOCATA challenge's submission format: reading (any tool's) and writing (doabench's) tracks.

Layout: ``<folder>/task<N>/recording<R>/<array>/source_<k>.txt``, one file per track ``k = 1..K``,
plus ``telapsed.txt`` (processing time in seconds; written, not read). A track file is
whitespace-separated (tabs as written) with one header line: ``year month day hour minute second``
of a required time stamp, then the estimate's fields, of which ``azimuth`` is read and
``elevation`` (the inclination from +z) when present, radians; other columns are ignored. NaN
marks a stamp without an estimate; a required stamp without a row has none either.

Reading refuses, with one line naming the file and line: a header without the time columns or
``azimuth``, a row with fewer or more fields than the header or a value that is not a number, a
time that is not one of ``required_time.txt``'s stamps (to within :data:`STAMP_TOLERANCE_S`) or
that repeats, an angle outside ``[-2 pi, 2 pi]`` (degrees where radians belong), a folder without
tracks and track numbers with holes.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from doabench.errors import InputError
from doabench.locata.stamps import nearest_index
from doabench.locata.tables import TIME_COLUMNS, TimeOrigin, seconds_since

STAMP_TOLERANCE_S = 1e-6  # the files' last decimal of a second
TRACK_RE = re.compile(r"^source_(\d+)\.txt$")
ANGLE_LIMIT = 2 * math.pi


def recording_folder(submission: Path, task: int, recording: int, array: str) -> Path:
    """``<submission>/task<N>/recording<R>/<array>``."""
    return Path(submission) / f"task{int(task)}" / f"recording{int(recording)}" / array


@dataclass
class Tracks:
    """A recording's tracks on its required rows: ``azimuth``/``inclination`` ``(K, Q)`` radians,
    NaN where a track has no estimate (``inclination`` all NaN for tracks without ``elevation``)."""

    folder: Path
    files: list[Path]
    azimuth: np.ndarray
    inclination: np.ndarray


def track_files(folder: Path) -> list[Path]:
    """``source_1.txt .. source_K.txt`` of ``folder`` in track order; InputError when there are
    none or the numbers have holes."""
    if not folder.is_dir():
        raise InputError(f"submission has no tracks for this recording: folder {folder} does not exist")
    found: dict[int, Path] = {}
    for path in folder.iterdir():
        m = TRACK_RE.match(path.name)
        if m:
            k = int(m.group(1))
            if k in found:
                raise InputError(f"submission folder {folder}: {found[k].name} and {path.name} are the same track")
            found[k] = path
    if not found:
        raise InputError(f"submission has no tracks for this recording: no source_<k>.txt in {folder}")
    numbers = sorted(found)
    if numbers != list(range(1, len(numbers) + 1)):
        gap = next(k for k in range(1, numbers[-1] + 1) if k not in found)
        raise InputError(f"submission folder {folder}: source_{gap}.txt is missing (tracks are numbered 1..K "
                         f"without holes; found {', '.join(map(str, numbers))})")
    return [found[k] for k in numbers]


def _parse(path: Path) -> tuple[list[str], np.ndarray, np.ndarray]:
    """``(header, values (rows, columns), line number of each row (rows,))`` of a track file (blank
    lines skipped); InputError naming the line of a row that does not fit the header or holds a
    value that is not a number."""
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read track file {path} ({type(exc).__name__})") from None
    header = lines[0].split() if lines else []
    missing = [c for c in (*TIME_COLUMNS, "azimuth") if c not in header]
    if missing:
        raise InputError(f"track file {path} line 1: the header lacks column(s) {', '.join(missing)} "
                         f"(expected {' '.join(TIME_COLUMNS)} azimuth elevation ...)")
    rows, numbers = [], []
    for number, line in enumerate(lines[1:], start=2):
        fields = line.split()
        if not fields:
            continue
        if len(fields) != len(header):
            raise InputError(f"track file {path} line {number}: {len(fields)} fields, the header has {len(header)} "
                             "(missing or extra columns)")
        try:
            rows.append([float(f) for f in fields])
            numbers.append(number)
        except ValueError:
            bad = next(f for f in fields if not _is_number(f))
            raise InputError(f"track file {path} line {number}: {bad!r} is not a number") from None
    return header, np.asarray(rows, np.float64).reshape(len(rows), len(header)), np.asarray(numbers, np.int64)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def read_track(path: Path, required_times: np.ndarray, origin: TimeOrigin) -> tuple[np.ndarray, np.ndarray | None]:
    """One track file on the required rows ``(Q,)`` (seconds since ``origin``): ``(azimuth (Q,),
    inclination (Q,) or None)``, NaN where the file gives no estimate. InputError naming the file
    and line for every problem in the module docstring."""
    header, values, lines = _parse(path)
    azimuth = np.full(len(required_times), np.nan)
    inclination = np.full(len(required_times), np.nan) if "elevation" in header else None
    if len(values) == 0:
        return azimuth, inclination
    frame = pd.DataFrame(values[:, [header.index(c) for c in TIME_COLUMNS]], columns=list(TIME_COLUMNS))
    try:
        t = seconds_since(frame, path, origin)
    except InputError as exc:
        raise InputError(f"track file {str(exc).removeprefix('LOCATA table ')}") from None
    row = nearest_index(required_times, t)
    off = np.abs(t - required_times[row])
    bad = off > STAMP_TOLERANCE_S
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError(f"track file {path} line {lines[i]}: time {t[i]:.6f} s is not a required time stamp "
                         f"(the nearest is {required_times[row[i]]:.6f} s, {off[i]:.6f} s away; see required_time.txt)")
    _, first = np.unique(row, return_index=True)
    if len(first) < len(row):
        i = int(np.setdiff1d(np.arange(len(row)), first)[0])
        raise InputError(f"track file {path} line {lines[i]}: a second row for the stamp at {t[i]:.6f} s")
    columns = [("azimuth", azimuth)] + ([("elevation", inclination)] if inclination is not None else [])
    for name, out in columns:
        angle = values[:, header.index(name)]
        outside = ~np.isnan(angle) & ~(np.abs(angle) <= ANGLE_LIMIT)
        if outside.any():
            i = int(np.argmax(outside))
            raise InputError(f"track file {path} line {lines[i]}: {name} {angle[i]:g} is outside [-2pi, 2pi] "
                             "(angles are radians; degrees given?)")
        out[row] = angle
    return azimuth, inclination


def read_tracks(folder: Path, required_times: np.ndarray, origin: TimeOrigin) -> Tracks:
    """Every track of a submission's recording folder on the required rows (see :func:`read_track`)."""
    files = track_files(folder)
    azimuth, inclination = [], []
    for path in files:
        az, inc = read_track(path, required_times, origin)
        azimuth.append(az)
        inclination.append(inc if inc is not None else np.full_like(az, np.nan))
    return Tracks(folder, files, np.stack(azimuth), np.stack(inclination))


# -- writing -----------------------------------------------------------------------------------
def required_calendar(path: Path) -> list[str]:
    """The time columns of every data row of ``required_time.txt``, as written there (tab-joined),
    so a written track's times are the required stamps exactly."""
    lines = [line.split() for line in Path(path).read_text(encoding="utf-8").splitlines()]
    header = lines[0] if lines else []
    if list(header[:6]) != list(TIME_COLUMNS):
        raise InputError(f"LOCATA table {path}: its header does not start with {' '.join(TIME_COLUMNS)}")
    return ["\t".join(fields[:6]) for fields in lines[1:] if fields]


def track_text(calendar: list[str], azimuth: np.ndarray, inclination: np.ndarray) -> str:
    """A track file's text: one row per required stamp (``calendar`` from :func:`required_calendar`),
    ``azimuth`` and ``elevation`` ``(Q,)`` radians (NaN: no estimate)."""
    if not len(calendar) == len(azimuth) == len(inclination):
        raise ValueError(f"{len(calendar)} stamps, {len(azimuth)} azimuths, {len(inclination)} elevations")
    rows = ["\t".join((*TIME_COLUMNS, "azimuth", "elevation"))]
    rows += [f"{c}\t{_angle_text(a)}\t{_angle_text(e)}" for c, a, e in
             zip(calendar, np.asarray(azimuth, float).tolist(), np.asarray(inclination, float).tolist())]
    return "\n".join(rows) + "\n"


def _angle_text(x: float) -> str:
    return "NaN" if math.isnan(x) else f"{x:.9f}"
