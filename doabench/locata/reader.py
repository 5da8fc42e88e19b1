"""Read one LOCATA recording into an :class:`~doabench.episode.Episode` at 16 kHz.

Timing rules (docs/locata.md explains them with the reasons):

1. The recording's time origin is its first array-audio time stamp; every table (array audio,
   poses, required times, source audio) is converted to seconds since that origin from its own
   calendar columns. Audio time stamps must strictly increase; pose and required-time rows must
   be in time order (a row going back in time is an InputError naming the file and line).
2. The array audio (48 kHz) is resampled to ``fs`` (16 kHz) with ``scipy.signal.resample_poly``
   (a Kaiser-windowed FIR anti-aliasing filter, zero-phase, so output sample ``n`` is aligned
   with input sample ``n * down / up``). Output sample ``n`` gets the time stamp of that input
   position, interpolated from the recorded time stamps (the nominal rate is never assumed).
3. The episode spans the required-time rows: samples further than half a required-time step
   before the first row or after the last are cut off.
4. Poses are interpolated to every output sample (truth module); the direction is
   ``R^T (s - p)`` in the array frame.
5. A sample is *valid* when its nearest required-time row has ``valid_flag = 1`` and both the
   array and the source pose cover it (within one pose period). Invalid samples are left out of
   scoring (``Episode.sample_valid``; they are also not voice-active in ``sample_vad``), but the
   features are masked with the voice activity alone (``Episode.input_vad``): an invalid frame's
   map reaches the network as it is, not zeroed.
6. Voice activity, ``vad=``:

   * ``webrtc`` (the paper's, the tasks' default): the WebRTC VAD (doabench.corpora.vad) of the
     array audio (first microphone at ``fs``, peak-normalised); metadata ``vad_source`` =
     ``webrtcvad-array``;
   * ``corpus``: the corpus file ``VAD_<array>_<name>.txt`` (one value per array sample; output
     sample ``n`` takes the value of input sample ``round(n * down / up)``); ``vad_source`` =
     ``corpus``;
   * ``auto``: the corpus file when present, else the WebRTC VAD of the clean source signal, put
     on the array clock by linear interpolation at the array-audio time stamps and resampled like
     the array audio (``vad_source`` = ``webrtcvad``).
"""
from __future__ import annotations

import struct
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import soundfile as sf

from doabench.arrays import MicArray, get_array
from doabench.episode import Episode
from doabench.errors import ConfigError, InputError, NotFoundError
from doabench.locata.layout import Recording, require
from doabench.locata.tables import (Pose, TimeOrigin, read_pose, read_required_time, read_times, read_vad)
from doabench.locata.truth import (array_frame_directions, coverage_mask, local_mic_positions, required_mask)
from doabench.resampling import rational_factors, resample

VAD_MODES = ("webrtc", "corpus", "auto")
MIC_SPREAD_WARN_M = 0.005  # a rigid array's microphones should not wander by more than this
# The built-in geometry used when a position_array file has no microphone columns.
_BUILTIN_GEOMETRY = {"benchmark2": "benchmark2"}


def wav_declared_frames(path: Path) -> int | None:
    """Frames the RIFF header of a PCM/float WAV declares in its ``data`` chunk, or None when the
    header cannot be read this way (then only the time-stamp count is checked)."""
    try:
        with open(path, "rb") as f:
            head = f.read(12)
            if len(head) < 12 or head[:4] != b"RIFF" or head[8:12] != b"WAVE":
                return None
            block_align = None
            while True:
                chunk = f.read(8)
                if len(chunk) < 8:
                    return None
                cid, size = chunk[:4], struct.unpack("<I", chunk[4:])[0]
                if cid == b"fmt ":
                    fmt = f.read(size + (size & 1))
                    block_align = struct.unpack("<H", fmt[12:14])[0]
                elif cid == b"data":
                    # 0 and 0xFFFFFFFF mark "unknown length" (streamed or RF64 files): no check then.
                    return None if not block_align or size in (0, 0xFFFFFFFF) else size // block_align
                else:
                    f.seek(size + (size & 1), 1)
    except (OSError, struct.error):
        return None


def read_wav(path: Path, what: str, expected_frames: int | None = None) -> tuple[np.ndarray, int]:
    """``(samples (L, C) float64, fs)``. InputError naming the file when it cannot be decoded, is
    shorter than its header declares, or has not ``expected_frames`` frames (its time stamps)."""
    require(path, what)
    try:
        data, fs = sf.read(str(path), dtype="float64", always_2d=True)
    except (sf.LibsndfileError, RuntimeError, TypeError) as exc:
        raise InputError(f"cannot read WAV {path} ({exc})") from None
    declared = wav_declared_frames(path)
    if declared is not None and data.shape[0] < declared:
        raise InputError(f"WAV {path} is truncated: its header declares {declared} frames, the file holds "
                         f"{data.shape[0]}")
    if expected_frames is not None and data.shape[0] != expected_frames:
        raise InputError(f"WAV {path} has {data.shape[0]} frames but its time-stamp file lists {expected_frames} "
                         "(truncated or mismatched file)")
    return data, int(fs)


def _resample(x: np.ndarray, fs_in: int, fs_out: int) -> tuple[np.ndarray, int, int]:
    """``(y, up, down)``: :func:`doabench.resampling.resample` along the sample axis (0) and its
    factors (for provenance); float64 when the rates are equal."""
    up, down = rational_factors(fs_in, fs_out)
    y = resample(x, fs_in, fs_out, axis=0)
    return (np.asarray(y, dtype=np.float64) if up == down == 1 else y), up, down


def _choose_source(rec: Recording, source: str | None) -> str:
    names = rec.source_names()
    if source is not None:
        if source not in names:
            raise NotFoundError(f"LOCATA recording {rec.path} has no source {source!r} "
                                f"(found: {', '.join(names) or 'none'})")
        return source
    if not names:
        raise NotFoundError(f"LOCATA ground truth missing: no {rec.path}/position_source_<name>.txt "
                            f"({rec.split} split; copies of the original eval release have no source positions)")
    if len(names) > 1:
        raise InputError(f"LOCATA recording {rec.path} has {len(names)} sources ({', '.join(names)}); "
                         "single-source tasks expect one (pass source=NAME)")
    return names[0]


def _geometry(rec: Recording, pose: Pose, n_channels: int) -> tuple[MicArray, dict[str, Any]]:
    """The array geometry: the recording's own microphone columns, else the built-in one."""
    if pose.mics is not None:
        local, spread = local_mic_positions(pose)
        if local.shape[0] != n_channels:
            raise InputError(f"{rec.array_position_file} has {local.shape[0]} microphones but "
                             f"{rec.audio_file.name} has {n_channels} channels")
        if spread > MIC_SPREAD_WARN_M:
            warnings.warn(f"{rec.array_position_file}: microphone positions in the array frame vary by up to "
                          f"{spread * 1000:.1f} mm over time; using their time average", stacklevel=3)
        base = get_array(_BUILTIN_GEOMETRY[rec.array]) if rec.array in _BUILTIN_GEOMETRY else None
        if base is not None:
            array = base.with_positions(local, source=str(rec.array_position_file))
        else:
            array = MicArray(rec.array, local, source=str(rec.array_position_file))  # planar if it is
        return array, {"mic_geometry": "recording", "mic_geometry_spread_m": spread}
    if rec.array not in _BUILTIN_GEOMETRY:
        raise NotFoundError(f"{rec.array_position_file} has no mic<k>_x/y/z columns and doabench has no built-in "
                            f"geometry for array {rec.array!r}")
    array = get_array(_BUILTIN_GEOMETRY[rec.array])
    if array.n_mics != n_channels:
        raise InputError(f"{rec.audio_file} has {n_channels} channels; built-in array {array.name!r} has "
                         f"{array.n_mics} microphones")
    return array, {"mic_geometry": "builtin", "mic_geometry_spread_m": None}


def _corpus_vad(rec: Recording, name: str, n_in: int, take: np.ndarray) -> np.ndarray:
    vad = read_vad(rec.vad_file(name))
    if len(vad) != n_in:
        raise InputError(f"LOCATA VAD file {rec.vad_file(name)} has {len(vad)} values but {rec.audio_file.name} "
                         f"has {n_in} samples")
    return vad[take]


def _webrtc_vad(rec: Recording, name: str, origin: TimeOrigin, t_in: np.ndarray, fs_in: int, fs_out: int
                ) -> tuple[np.ndarray, int]:
    """WebRTC VAD of the source signal on the array clock: ``(vad at fs_out (L_out,), mode)``."""
    from doabench.corpora.vad import webrtc_vad

    t_src, _ = read_times(require(rec.source_timestamps_file(name), "source audio time stamps"),
                          "source audio time stamps", origin)
    src, fs_src = read_wav(rec.source_audio_file(name), "source signal", expected_frames=len(t_src))
    # The source's own clock: its samples are placed at the array's sample times (0 outside).
    on_array_clock = np.interp(t_in, t_src, src[:, 0], left=0.0, right=0.0)
    y, _, _ = _resample(on_array_clock, fs_in, fs_out)
    return webrtc_vad(np.clip(y, -1.0, 1.0), fs_out)


def read_recording(rec: Recording, fs: int = 16000, vad: str = "auto", source: str | None = None) -> Episode:
    """The episode of one recording (see the module docstring for every rule).

    Returns an Episode with ``audio (M, L) float32`` at ``fs``, ``sample_vad (L,)`` (voice active
    and valid), ``sample_directions (L, 3)`` in the array frame, ``array`` = the recording's
    geometry and metadata (recording, split, task, array, source, vad_source, timing, geometry).
    """
    if vad not in VAD_MODES:
        raise ConfigError(f"LOCATA vad option {vad!r} is not one of {', '.join(VAD_MODES)}")
    name = _choose_source(rec, source)
    require(rec.audio_file, "array audio")
    t_in, origin = read_times(rec.audio_timestamps_file, "array audio time stamps, one per sample")
    audio, fs_in = read_wav(rec.audio_file, "array audio", expected_frames=len(t_in))
    array_pose = read_pose(rec.array_position_file, "array pose", origin, with_mics=True)
    source_pose = read_pose(rec.source_position_file(name), "source position (ground truth)", origin,
                            with_mics=False)
    req_t, req_valid = read_required_time(rec.required_time_file, origin)
    array, geometry_meta = _geometry(rec, array_pose, audio.shape[1])

    y, up, down = _resample(audio, fs_in, fs)
    positions = np.arange(y.shape[0]) * (down / up)  # input-sample position of each output sample
    t_out = np.interp(positions, np.arange(len(t_in)), t_in)
    take = np.minimum(np.rint(positions).astype(np.int64), len(t_in) - 1)

    # 3. keep the samples within the required-time span
    req_step = float(np.median(np.diff(req_t))) if len(req_t) > 1 else 0.0
    span = coverage_mask(req_t, t_out, req_step / 2)
    if not span.any():
        raise InputError(f"{rec.required_time_file}: its time span "
                         f"[{req_t[0]:.3f}, {req_t[-1]:.3f}] s does not overlap the array audio "
                         f"[{t_in[0]:.3f}, {t_in[-1]:.3f}] s")
    first, last = int(np.argmax(span)), int(len(span) - np.argmax(span[::-1]))
    sl = slice(first, last)
    t = t_out[sl]

    # 4.-5. truth and validity
    directions = array_frame_directions(array_pose, source_pose, t)
    pose_step = lambda p: float(np.median(np.diff(p.times))) if len(p.times) > 1 else 0.0  # noqa: E731
    valid = (required_mask(req_t, req_valid, t)
             & coverage_mask(array_pose.times, t, pose_step(array_pose))
             & coverage_mask(source_pose.times, t, pose_step(source_pose)))

    # 6. voice activity
    vad_meta: dict[str, Any]
    if vad == "webrtc":
        from doabench.corpora.vad import webrtc_vad

        ref = np.asarray(y[:, 0], dtype=np.float64)
        full, mode = webrtc_vad(np.clip(0.5 * ref / (np.abs(ref).max() + 1e-12), -1.0, 1.0), fs)
        active = full[sl]
        vad_meta = {"vad_source": "webrtcvad-array", "vad_mode": int(mode)}
    elif rec.vad_file(name).is_file():
        active = _corpus_vad(rec, name, len(t_in), take)[sl]
        vad_meta = {"vad_source": "corpus", "vad_file": rec.vad_file(name).name}
    elif vad == "corpus":
        raise NotFoundError(f"LOCATA file missing: {rec.vad_file(name)} (vad='corpus' was asked for)")
    else:
        if not rec.source_audio_file(name).is_file():
            raise NotFoundError(f"LOCATA voice activity missing: neither {rec.vad_file(name)} nor "
                                f"{rec.source_audio_file(name)} (for the WebRTC VAD) exists")
        full, mode = _webrtc_vad(rec, name, origin, t_in, fs_in, fs)
        active = full[: y.shape[0]][sl]
        vad_meta = {"vad_source": "webrtcvad", "vad_mode": int(mode)}

    metadata = {
        "recording": rec.number,
        "locata_task": rec.task,
        "split": rec.split,
        "array_name": rec.array,
        "source_name": name,
        "recording_id": rec.id,
        "path": str(rec.path),
        **vad_meta,
        **geometry_meta,
        "fs_original": fs_in,
        "resampler": f"scipy.signal.resample_poly(up={up}, down={down})",
        "rotation_interpolation": "linear + polar re-orthonormalisation",
        "time_origin": origin.text(),
        "start_s": float(t[0]),
        "duration_s": float(t[-1] - t[0] + 1.0 / fs),
        "samples_cut": int(y.shape[0] - (last - first)),
        "valid_fraction": float(valid.mean()),
        "vad_fraction": float(active.mean()),
        "pose_rows_dropped": int(array_pose.dropped + source_pose.dropped),
    }
    return Episode(
        audio=np.ascontiguousarray(y[sl].T, dtype=np.float32),
        fs=int(fs),
        sample_vad=np.asarray(active & valid, dtype=bool),
        sample_directions=directions,
        metadata=metadata,
        array=array,
        sample_valid=np.asarray(valid, dtype=bool),
        input_vad=np.asarray(active, dtype=bool),
    )
