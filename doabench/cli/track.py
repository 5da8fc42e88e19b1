"""``doabench track REC.wav``: any tracker on the user's own multichannel recording."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from doabench.cli.common import add_tracker_options, check_output_file


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("track", help="track the source in your own multichannel recording",
                       description="Run a tracker on a WAV/FLAC recording (one channel per microphone) and "
                                   "write one direction per frame as CSV: time_s, elevation_deg, azimuth_deg, x, y, z, vad "
                                   "(1 when the frame is voice-active).")
    p.add_argument("recording", metavar="REC.wav")
    p.add_argument("--array", default="nao", help="built-in array name or JSON/YAML array file (default: nao)")
    add_tracker_options(p, required=False, default="srp-max")
    p.add_argument("--delays", choices=["nearest", "exact"], default="nearest")
    p.add_argument("--vad", choices=["webrtc", "none"], default="webrtc",
                   help="frame voice activity: WebRTC VAD on the channel mean (default) or every frame active")
    p.add_argument("--resample", action="store_true", help="resample a recording at another rate (anti-aliased)")
    p.add_argument("--device", default=None)
    p.add_argument("--out", required=True, help="output CSV")
    p.add_argument("--plot", help="also draw azimuth and elevation over time into this PNG/PDF")
    p.set_defaults(func=main)


def recording_vad(audio: np.ndarray, fs: int) -> np.ndarray:
    """Per-sample VAD ``(samples,)`` of a multichannel recording from the WebRTC VAD of its channel mean."""
    from doabench.acoustics.vad import webrtc_vad

    mono = audio.mean(0)
    peak = float(np.max(np.abs(mono))) or 1.0
    return webrtc_vad(mono / peak, fs)[0]


def track_recording(tracker, array, audio: np.ndarray, sample_vad: np.ndarray | None, delays: str = "nearest",
                    device: str | None = None) -> dict[str, np.ndarray]:
    """Features -> tracker -> ``{"times", "directions" (T, 3), "vad" (T,)}`` for one recording."""
    from doabench.features import FeatureExtractor
    from doabench.features.observations import extractor_kinds, recording_features
    from doabench.runner import _guarded, check_direction, check_directions

    spec = tracker.frame_spec
    extractor = FeatureExtractor(array, kinds=extractor_kinds(tracker.features), resolution=tracker.resolution or (16, 32),
                                 mode=delays, frame_spec=spec, spectrogram_frame_spec=spec)
    feats = recording_features(extractor, audio, sample_vad, tracker.features, spec, device)
    n = len(feats["vad"])
    _guarded(tracker, "reset()", lambda: tracker.reset(array, frame_spec=spec))
    if tracker.causal:
        directions = np.stack([check_direction(tracker, _guarded(
            tracker, f"step() at frame {t}", tracker.step,
            {**{k: v[t] for k, v in feats.items()}, "vad": int(feats["vad"][t])}), t)
            for t in range(n)]) if n else np.zeros((0, 3))
    else:
        directions = check_directions(tracker, _guarded(tracker, "track()", tracker.track, feats), n)
    return {"times": spec.times(n), "directions": directions, "vad": feats["vad"].astype(bool)}


def check_plot_path(path: str | Path) -> None:
    """Refuse a ``--plot`` file whose format matplotlib cannot write (checked before any work)."""
    from matplotlib.backend_bases import FigureCanvasBase

    from doabench.errors import InputError

    formats = FigureCanvasBase.get_supported_filetypes()
    suffix = Path(path).suffix.lower().lstrip(".")
    if suffix not in formats:
        raise InputError(f"--plot {path}: unknown image format {suffix or '(no suffix)'!r}; use one of "
                         f"{', '.join(sorted(formats))}")


def plot_track(path: str | Path, times: np.ndarray, directions: np.ndarray, vad: np.ndarray, title: str) -> None:
    """Azimuth and elevation over time, silent frames shaded grey."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from doabench.geometry import unit_to_angles
    from doabench.results.files import atomic_path

    el, az = unit_to_angles(directions)
    fig, axes = plt.subplots(2, 1, sharex=True, figsize=(8, 4.5))
    for ax, values, label in ((axes[0], np.degrees(az), "azimuth [deg]"), (axes[1], np.degrees(el), "elevation [deg]")):
        ax.plot(times, values, ".-", lw=1, ms=3)
        ax.set_ylabel(label)
        half = (times[1] - times[0]) / 2 if len(times) > 1 else 0.1
        for t, active in zip(times, vad):
            if not active:
                ax.axvspan(t - half, t + half, color="0.85", lw=0)
    axes[0].set_ylim(-180, 180)
    axes[1].set_ylim(0, 180)
    axes[1].set_xlabel("time [s]")
    axes[0].set_title(title)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=Path(path).suffix.lstrip(".") or "png", dpi=120)
    plt.close(fig)


def main(args: argparse.Namespace) -> int:
    import pandas as pd

    from doabench.arrays import get_array
    from doabench.geometry import unit_to_angles
    from doabench.recording import load_recording
    from doabench.results.files import atomic_path
    from doabench.trackers.registry import make_tracker, parse_options

    # Every output is checked before the work: none may be an input, a folder or unwritable.
    check_output_file(args.out, [args.recording, args.array], "--out")
    if args.plot:
        check_output_file(args.plot, [args.recording, args.array, args.out], "--plot")
        check_plot_path(args.plot)
    tracker = make_tracker(args.tracker, **parse_options(args.tracker_opt))
    from doabench.runner import check_trained

    check_trained(tracker)  # an untrained learned model is refused unless weights=random
    array = get_array(args.array)
    spec = tracker.frame_spec
    audio, _ = load_recording(args.recording, array, spec.fs, args.resample, min_samples=spec.window)
    silent = not np.any(audio)
    if silent:  # no frame of digital silence is voice-active, whatever --vad says
        sample_vad = np.zeros(audio.shape[-1], bool)
    else:
        sample_vad = recording_vad(audio, spec.fs) if args.vad == "webrtc" else None
    out = track_recording(tracker, array, audio, sample_vad, args.delays, args.device)
    if silent or not out["vad"].any():
        why = "the recording is digital silence (all samples zero)" if silent else "the VAD found no speech"
        print(f"doabench track: warning: no frame was voice-active ({why}); the directions of silent frames "
              "carry no information (see the vad column)", file=sys.stderr)
    el, az = unit_to_angles(out["directions"])
    table = pd.DataFrame({"time_s": out["times"], "elevation_deg": np.degrees(el), "azimuth_deg": np.degrees(az),
                          "x": out["directions"][:, 0], "y": out["directions"][:, 1], "z": out["directions"][:, 2],
                          "vad": np.asarray(out["vad"], np.int8)})
    with atomic_path(args.out) as tmp:
        table.to_csv(tmp, index=False, float_format="%.4f")
    print(f"wrote {args.out}: {len(table)} frames from {args.recording} with {args.tracker}")
    if args.plot:
        plot_track(args.plot, out["times"], out["directions"], out["vad"], f"{Path(args.recording).name}: {args.tracker}")
        print(f"wrote {args.plot}")
    return 0
