"""``doabench features``: compute one feature kind of a recording and save it as ``.npy`` + JSON.

    doabench features REC.wav --array nao --kind srp --resolution 16x32 --out maps.npy

writes ``maps.npy`` (``(frames, ...)`` float32) and ``maps.json`` (settings, array, frame times,
and what the kind says of its axes: grid angles in degrees for maps, pairs and lags for GCC, ...).
Both are written atomically. ``--kind`` is any computed kind, a plug-in's included.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from doabench.geometry import resolution_text
from doabench.errors import ConfigError, NotFoundError
from doabench.features.kinds import EXTRACTOR_KINDS, FeatureKind, call_kind, feature_kind
from doabench.files import atomic_path, write_text
from doabench.framing import DEFAULT_FS, DEFAULT_WINDOW, FrameSpec

HELP = "compute SRP-PHAT maps, GCC-PHAT or spectrograms of a WAV recording"


def register(subparsers) -> None:
    p = subparsers.add_parser("features", help=HELP, description=HELP + ".")
    p.add_argument("recording", metavar="REC.wav", help="multichannel recording (one channel per microphone)")
    p.add_argument("--array", default="nao", help="built-in array name or JSON/YAML array file (default: nao)")
    p.add_argument("--kind", default="srp", help=f"feature to compute: {', '.join(EXTRACTOR_KINDS)} or a plug-in's "
                                                 "(default: srp)")
    p.add_argument("--resolution", default="16x32", help="SRP grid N_THETAxN_PHI (default: 16x32)")
    p.add_argument("--delays", default="nearest", choices=("nearest", "exact"), help="SRP delay evaluation (default: nearest, as the paper)")
    p.add_argument("--window", type=int, default=DEFAULT_WINDOW, help=f"frame length K in samples (default: {DEFAULT_WINDOW})")
    p.add_argument("--hop", type=int, default=None, help="hop in samples (default: 3K/4)")
    p.add_argument("--fs", type=int, default=DEFAULT_FS, help=f"sample rate the features are computed at (default: {DEFAULT_FS})")
    p.add_argument("--resample", action="store_true", help="resample a recording at another rate to --fs (polyphase, anti-aliased)")
    p.add_argument("--out", required=True, help="output .npy path; a .json sidecar is written next to it")
    p.set_defaults(func=run)


def read_audio_rate(path: Path) -> int:
    import soundfile as sf

    return int(sf.info(str(path)).samplerate)


def computed_kind(name: str) -> FeatureKind:
    """The registered kind ``name`` if it is computed from a recording, else a one-line error."""
    kind = feature_kind(name)
    if kind.compute is None:
        raise ConfigError(f"feature {kind.name!r} is the recording itself: nothing to compute; choose "
                          f"{', '.join(EXTRACTOR_KINDS)} or a plug-in kind")
    return kind


def _sidecar(args, kind: FeatureKind, extractor, result, sr: int, resampled: bool) -> dict:
    from doabench._version import __version__

    # ``result``: the feature array, or anything with its ``shape`` and ``dtype`` (the streamed file's)
    context = extractor.frame_context()
    spec: FrameSpec = kind.frames(context)
    meta = {
        "kind": kind.name,
        "shape": list(result.shape),
        "dtype": str(result.dtype),
        "recording": str(args.recording),
        "recording_fs": sr,
        "resampled": resampled,
        "frame": spec.to_dict(),
        "window_function": "hann (periodic)",
        "frame_times_s": spec.times(result.shape[0]).round(6).tolist(),
        "array": extractor.array.to_dict(),
        "speed_of_sound": extractor.c,
        "silent_frames": "none zeroed (no VAD given)",
        "doabench_version": __version__,
    }
    if kind.on_grid:
        meta.update(resolution=resolution_text(extractor.resolution), delays=extractor.mode)
    meta.update(call_kind(kind, "axes()", kind.axes, context) if kind.axes is not None
                else {"description": kind.description})
    return meta


class _Shape:
    """What :func:`_sidecar` reads of a feature array that was streamed to disk."""

    def __init__(self, shape: tuple[int, ...], dtype: np.dtype) -> None:
        self.shape, self.dtype = shape, dtype


def run(args) -> int:
    import torch

    from doabench.arrays import get_array
    from doabench.geometry import parse_resolution

    out = Path(args.out)
    if out.suffix.lower() == ".json":
        raise ConfigError(f"--out {out} must not end in .json: the sidecar gets that name")
    if not out.parent.is_dir():
        raise NotFoundError(f"output directory {out.parent} does not exist")
    from doabench.cli.common import check_output_file
    from doabench.files import resolve_output

    check_output_file(out, [args.recording, args.array], "--out")
    # A stream (-, /dev/stdout, a FIFO) carries the .npy alone: no sidecar beside a device or a pipe.
    sidecar = None if resolve_output(out).stream else out.with_suffix(".json")
    if sidecar is not None:
        check_output_file(sidecar, [args.recording, args.array], "--out (its .json sidecar)")
    kind = computed_kind(args.kind)
    array = get_array(args.array)
    spec = FrameSpec(args.window, args.hop, args.fs)
    resolution = parse_resolution(args.resolution)

    path = Path(args.recording)
    from doabench.features.streaming import StreamingFeatureExtractor
    from doabench.recording import BLOCK_SAMPLES, open_recording

    # Read block by block and write the .npy as the frames complete: neither the recording nor the
    # features are held whole, so memory does not grow with the recording's length.
    rec = open_recording(path, array, args.fs, args.resample, min_samples=spec.window)
    sr, resampled = rec.sr, rec.resampled
    stream = StreamingFeatureExtractor(
        array,
        kinds=(kind.name,),
        resolution=resolution,
        mode=args.delays,
        frame_spec=spec,
        spectrogram_frame_spec=spec,
    )
    extractor = stream.extractor
    shape = (spec.n_frames(rec.samples), *extractor.feature_shapes()[kind.name])
    result = _Shape(shape, np.dtype(np.float32))
    # the sidecar is described first: a kind whose axes() fails stops the command before any file
    meta = None if sidecar is None else _sidecar(args, kind, extractor, result, sr, resampled)
    written = 0
    with atomic_path(out) as tmp:
        with open(tmp, "wb") as f:  # the header np.save writes, then the frames as they complete
            np.lib.format.write_array_header_1_0(f, np.lib.format.header_data_from_array_1_0(
                np.empty((0,), np.float32)) | {"shape": shape})
            with torch.inference_mode():
                for x in rec.blocks(BLOCK_SAMPLES):
                    part = stream.push(torch.from_numpy(x))[kind.name].numpy().astype(np.float32, copy=False)
                    f.write(np.ascontiguousarray(part).tobytes())
                    written += part.shape[0]
        if written != shape[0]:  # the frame count promised in the .npy header (from the file's header)
            from doabench.errors import InputError

            raise InputError(f"{path} holds fewer samples than its header says ({written} frames of "
                             f"{shape[0]} read): is it truncated?")
    if sidecar is None:
        print(f"wrote {out} {tuple(result.shape)} (a stream: no .json sidecar)")
        return 0
    write_text(sidecar, json.dumps(meta) + "\n")
    print(f"wrote {out} {tuple(result.shape)} and {sidecar}")
    return 0
