"""A run's per-frame estimates as a LOCATA track on a recording's required time stamps.

Every required stamp takes the latest estimate the tracker had given by then: a frame's estimate
exists once the frame's last sample has arrived (its window's end), so stamp ``t`` takes the frame
whose window ends last at or before ``t``; NaN before the first frame's end and where that frame's
estimate is "no source" (three NaNs, ``doabench.NO_SOURCE``): the stamp has no active track.
Directions are turned into LOCATA's angles (doabench.locata.stamps.locata_angles).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from doabench.locata.stamps import locata_angles
from doabench.locata.submission import recording_folder, required_calendar, track_text


def frame_ends(start_s: float, centres: np.ndarray, window: int, fs: int) -> np.ndarray:
    """Window ends ``(F,)`` in the recording's seconds of frames whose centres ``(F,)`` are
    counted from the episode's first sample, which lies at ``start_s``."""
    return float(start_s) + np.asarray(centres, np.float64) + window / (2.0 * fs)


def stamp_track(required_times: np.ndarray, ends: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(azimuth (Q,), inclination (Q,))`` radians at the required stamps ``(Q,)`` from frames
    ending at ``ends`` ``(F,)`` (increasing) with unit ``directions`` ``(F, 3)`` (rows of NaNs: no
    source); NaN before the first frame's end and where the latest frame says no source."""
    required_times = np.asarray(required_times, np.float64)
    latest = np.searchsorted(np.asarray(ends, np.float64), required_times, side="right") - 1
    if len(directions) == 0:
        return np.full(len(required_times), np.nan), np.full(len(required_times), np.nan)
    az, inc = locata_angles(np.asarray(directions, np.float64))
    known = latest >= 0
    pick = np.maximum(latest, 0)
    return np.where(known, az[pick], np.nan), np.where(known, inc[pick], np.nan)


def submission_files(folder: Path, task: int, recording: int, array: str, required_time_file: Path,
                     azimuth: np.ndarray, inclination: np.ndarray, seconds: float) -> dict[Path, str]:
    """The files of one recording's one-track submission: ``source_1.txt`` (one row per required
    stamp, times as ``required_time.txt`` writes them) and ``telapsed.txt`` (``seconds``)."""
    where = recording_folder(folder, task, recording, array)
    return {where / "source_1.txt": track_text(required_calendar(required_time_file), azimuth, inclination),
            where / "telapsed.txt": f"{seconds:.6f}\n"}
