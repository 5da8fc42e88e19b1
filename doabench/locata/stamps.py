"""The truth on a recording's required time stamps, as the challenge's evaluation scores it.

* Stamps: the rows of ``required_time.txt`` (all of them, for matching a submission's rows) and the
  scored ones, those whose ``valid_flag`` is 1; seconds since the recording's first array-audio
  time stamp (the reader's origin, docs/locata.md "Timing and alignment").
* Direction of each source in the array frame, ``v = R^T (h - p)`` from the pose tables
  interpolated to the stamps (doabench.locata.truth); LOCATA's angles: azimuth
  ``wrap(atan2(v_y, v_x) - pi/2)`` (measured from the array's +y axis), inclination
  ``acos(v_z / |v|)``, radians.
* Voice activity of each source on a stamp: the corpus VAD file ``VAD_<array>_<name>.txt`` at the
  array-audio sample nearest the stamp.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from doabench.errors import InputError, NotFoundError
from doabench.geometry import wrap_angle
from doabench.locata.layout import Recording, require
from doabench.locata.tables import TimeOrigin, read_pose, read_required_time, read_times, read_vad
from doabench.locata.truth import array_frame_directions


@dataclass
class StampTruth:
    """The truth of one recording on its stamps.

    * ``required_times`` ``(Q,)`` every row of ``required_time.txt``, ``valid`` ``(Q,)`` its flags;
    * ``times`` ``(T,)`` the scored stamps (``required_times[valid]``);
    * ``sources`` the source names (``S``), ``azimuth``/``inclination`` ``(S, T)`` radians in
      LOCATA's convention, ``vad`` ``(S, T)`` bool;
    * ``origin``: the calendar time the seconds count from.
    """

    recording: Recording
    origin: TimeOrigin
    required_times: np.ndarray
    valid: np.ndarray
    sources: tuple[str, ...]
    azimuth: np.ndarray
    inclination: np.ndarray
    vad: np.ndarray

    @property
    def times(self) -> np.ndarray:
        return self.required_times[self.valid]


def locata_angles(directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """LOCATA's ``(azimuth, inclination)`` of array-frame vectors ``(N, 3)``: azimuth from +y,
    ``wrap(atan2(y, x) - pi/2)``, and inclination from +z, radians ``(N,)`` each."""
    v = np.asarray(directions, np.float64)
    norm = np.linalg.norm(v, axis=-1)
    azimuth = wrap_angle(np.arctan2(v[:, 1], v[:, 0]) - math.pi / 2)
    inclination = np.arccos(np.clip(v[:, 2] / np.where(norm > 0, norm, 1.0), -1.0, 1.0))
    return azimuth, inclination


def nearest_index(times: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Index into increasing ``times`` ``(N,)`` of the value nearest each of ``at`` ``(M,)``
    (the earlier one on a tie)."""
    if len(times) == 1:
        return np.zeros(len(at), np.int64)
    i = np.clip(np.searchsorted(times, at), 1, len(times) - 1)
    return np.where(at - times[i - 1] <= times[i] - at, i - 1, i)


def stamp_truth(rec: Recording) -> StampTruth:
    """Read the truth of ``rec`` on its required time stamps (see the module docstring).

    NotFoundError when the recording has no ``position_source_<name>.txt`` (no ground truth) or
    lacks a VAD file; InputError for a VAD file whose length is not the array audio's."""
    names = sorted(p.name[len("position_source_"):-len(".txt")] for p in rec.path.glob("position_source_*.txt"))
    if not names:
        raise NotFoundError(f"LOCATA ground truth missing: no {rec.path}/position_source_<name>.txt "
                            f"({rec.split} split; copies of the original eval release have no source positions)")
    t_audio, origin = read_times(require(rec.audio_timestamps_file, "array audio time stamps, one per sample"),
                                 "array audio time stamps, one per sample")
    required, valid = read_required_time(rec.required_time_file, origin)
    times = required[valid]
    if times.size == 0:
        raise InputError(f"LOCATA table {rec.required_time_file}: no row has valid_flag 1 (nothing to score)")
    array_pose = read_pose(rec.array_position_file, "array pose", origin, with_mics=False)
    sample = nearest_index(t_audio, times)
    azimuth, inclination, vad = [], [], []
    for name in names:
        source_pose = read_pose(rec.source_position_file(name), "source position (ground truth)", origin,
                                with_mics=False)
        az, inc = locata_angles(array_frame_directions(array_pose, source_pose, times))
        azimuth.append(az)
        inclination.append(inc)
        activity = read_vad(rec.vad_file(name))
        if len(activity) != len(t_audio):
            raise InputError(f"LOCATA VAD file {rec.vad_file(name)} has {len(activity)} values but "
                             f"{rec.audio_timestamps_file.name} lists {len(t_audio)} samples")
        vad.append(activity[sample])
    return StampTruth(rec, origin, required, valid, tuple(names), np.stack(azimuth), np.stack(inclination),
                      np.stack(vad))
