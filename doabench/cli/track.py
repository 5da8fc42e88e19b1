"""``doabench track REC.wav``: any tracker on the user's own multichannel recording.

The tracking itself (features, the tracker loop) is :mod:`doabench.runner.recordings`; this module
checks the arguments and writes the CSV table and the plot."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from doabench.cli.common import (add_tracker_options, check_output_file, command_line, make_checked_tracker,
                                 set_interrupt_note)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("track", help="track the source in your own multichannel recording",
                       description="Run a tracker on a WAV/FLAC recording (one channel per microphone) and "
                                   "write one direction per frame as CSV: time_s, elevation_deg, azimuth_deg, x, y, z, vad "
                                   "(1 when the frame is voice-active).")
    p.add_argument("recording", metavar="REC.wav")
    p.add_argument("--array", default="nao", help="built-in array name or JSON/YAML array file (default: nao)")
    add_tracker_options(p, required=False, default="srp-max")
    p.add_argument("--delays", choices=["nearest", "exact"], default=None,
                   help="SRP-PHAT delay mode (default: the one the tracker's weights were trained on, else nearest)")
    p.add_argument("--vad", choices=["webrtc", "none", "truth"], default="webrtc",
                   help="frame voice activity: WebRTC VAD on the channel mean (default), every frame active, or "
                        "truth: the vad column of --truth (as `doabench run` uses the scene's VAD, so a "
                        "`doabench simulate --task T --episode N` recording scores as that episode of the run)")
    p.add_argument("--resample", action="store_true", help="resample a recording at another rate (anti-aliased)")
    p.add_argument("--device", default=None)
    p.add_argument("--out", required=True, help="output CSV")
    p.add_argument("--plot", help="also draw azimuth and elevation (the polar angle from the zenith) over time into "
                                  "this PNG/PDF, the legend right of the panels")
    p.add_argument("--truth", metavar="truth.csv",
                   help="score against a truth table (as `doabench simulate` writes: time_s, ..., x, y, z, vad per "
                        "frame; an optional valid column leaves frames with invalid truth unscored), as `doabench "
                        "run` scores (planar arrays folded): prints the RMSAE and lag, adds an error_deg column "
                        "and draws the truth in --plot")
    p.set_defaults(func=main)


def track_table(out: dict[str, np.ndarray]):
    """The CSV's table (time_s, elevation_deg, azimuth_deg, x, y, z, vad) of a tracking result."""
    import pandas as pd

    from doabench.geometry import unit_to_angles

    el, az = unit_to_angles(out["directions"])
    return pd.DataFrame({"time_s": out["times"], "elevation_deg": np.degrees(el), "azimuth_deg": np.degrees(az),
                         "x": out["directions"][:, 0], "y": out["directions"][:, 1], "z": out["directions"][:, 2],
                         "vad": np.asarray(out["vad"], np.int8)})


def check_plot_path(path: str | Path) -> None:
    """Refuse a ``--plot`` file whose format matplotlib cannot write (checked before any work)."""
    from matplotlib.backend_bases import FigureCanvasBase

    from doabench.errors import InputError

    formats = FigureCanvasBase.get_supported_filetypes()
    suffix = Path(path).suffix.lower().lstrip(".")
    if suffix not in formats:
        raise InputError(f"--plot {path}: unknown image format {suffix or '(no suffix)'!r}; use one of "
                         f"{', '.join(sorted(formats))}")


def read_truth(path: str | Path, n_frames: int, times: np.ndarray) -> dict[str, np.ndarray]:
    """A per-frame truth table (``doabench simulate``'s truth.csv): directions ``(T, 3)``, vad and
    valid ``(T,)`` (every frame valid without a ``valid`` column)."""
    import pandas as pd

    from doabench.errors import InputError

    try:
        table = pd.read_csv(path)
    except FileNotFoundError:
        raise InputError(f"--truth {path} does not exist") from None
    except Exception as exc:
        raise InputError(f"--truth {path} is not a CSV table ({type(exc).__name__}: {exc})") from None
    missing = [c for c in ("x", "y", "z") if c not in table.columns]
    if missing:
        raise InputError(f"--truth {path} lacks column(s) {', '.join(missing)} (expected time_s, elevation_deg, "
                         "azimuth_deg, x, y, z, vad as `doabench simulate` writes)")
    if len(table) != n_frames:
        raise InputError(f"--truth {path} has {len(table)} frames but the tracker makes {n_frames} of the recording "
                         "(the truth must be on the tracker's frame grid, K = 4096 and hop 3072 at 16 kHz)")
    if "time_s" in table.columns and not np.allclose(table["time_s"].to_numpy(float), times, atol=1e-3):
        raise InputError(f"--truth {path}: its frame times differ from the tracker's (another frame spec?)")
    d = table[["x", "y", "z"]].to_numpy(float)
    norms = np.linalg.norm(d, axis=1)
    if not np.all(np.isfinite(d)) or np.any(norms == 0):
        raise InputError(f"--truth {path}: x, y, z must be finite, non-zero directions")
    vad = table["vad"].to_numpy().astype(bool) if "vad" in table.columns else np.ones(len(table), bool)
    valid = table["valid"].to_numpy().astype(bool) if "valid" in table.columns else np.ones(len(table), bool)
    return {"directions": d / norms[:, None], "vad": vad, "valid": valid, "has_vad": "vad" in table.columns}


def score_line(path: str | Path, m: dict, planar: bool) -> str:
    """What ``track --truth`` prints: the metrics of :func:`doabench.metrics.score_episode`."""
    lag = "-" if m.get("lag_s") is None else f"{m['lag_s']:.2f} s"
    notes = [f"{m['frames_invalid']} frames with invalid truth not scored"] if m.get("frames_invalid") else []
    if planar:
        notes.append("planar array: scored against mirror-folded truth")
    return (f"scored against {path}: RMSAE {m['rmsae_all']:.2f} deg all frames, {m['rmsae_nonsilent']:.2f} deg "
            f"non-silent (truth's vad); MAE {m['mae']:.2f}, median {m['median']:.2f}; lag {lag}"
            + (f" ({m['lag_note']})" if m.get("lag_note") else "") + ("; " + "; ".join(notes) if notes else ""))


#: the y label of the elevation panel: doabench's elevation is the inclination from +z (the zenith)
ELEVATION_LABEL = "elevation θ [deg]\n(polar angle from zenith)"
AZIMUTH_LABEL = "azimuth φ [deg]"


def track_figure(times: np.ndarray, directions: np.ndarray, vad: np.ndarray, title: str,
                 truth: np.ndarray | None = None):
    """The figure of :func:`plot_track` (tests inspect it): azimuth above elevation over time,
    silent frames shaded grey, the legend right of the panels, clear of the curves."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    from doabench.geometry import unit_to_angles
    from doabench.reporting.plots import legend_outside

    el, az = unit_to_angles(directions)
    true_angles = None if truth is None else unit_to_angles(truth)
    fig, axes = plt.subplots(2, 1, sharex=True, figsize=(8, 4.5))
    for i, (ax, values, label) in enumerate(((axes[0], np.degrees(az), AZIMUTH_LABEL),
                                             (axes[1], np.degrees(el), ELEVATION_LABEL))):
        if true_angles is not None:
            ax.plot(times, np.degrees(true_angles[1 - i]), "-", color="C3", lw=1.6, label="truth")
        ax.plot(times, values, ".-", lw=1, ms=3, color="C0", label="estimate")
        ax.set_ylabel(label)
        half = (times[1] - times[0]) / 2 if len(times) > 1 else 0.1
        for t, active in zip(times, vad):
            if not active:
                ax.axvspan(t - half, t + half, color="0.85", lw=0)
    handles, _ = axes[0].get_legend_handles_labels()
    if not np.all(vad):
        handles.append(Patch(color="0.85", label="silent frames\n(no voice activity)"))
    legend_outside(axes[0], handles=handles)
    axes[0].set_ylim(-180, 180)
    axes[1].set_ylim(0, 180)
    axes[1].set_xlabel("time [s]")
    axes[0].set_title(title)
    fig.tight_layout()
    return fig


def plot_title(recording: str | Path, tracker_text: str, record: Mapping[str, Any]) -> str:
    """The plot's title: the recording, the tracker as typed and its weights by name (or file and
    hash; :func:`doabench.cli.weights_text.weights_label`), since ``cross3d`` alone names no weights."""
    from doabench.cli.weights_text import weights_label

    weights = weights_label(record)
    return f"{Path(recording).name}: {tracker_text}" + (f", {weights}" if weights else "")


def plot_track(path: str | Path, times: np.ndarray, directions: np.ndarray, vad: np.ndarray, title: str,
               truth: np.ndarray | None = None) -> None:
    """Write :func:`track_figure` to ``path`` (its suffix names the format)."""
    import matplotlib.pyplot as plt

    from doabench.files import atomic_path

    fig = track_figure(times, directions, vad, title, truth)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=Path(path).suffix.lstrip(".") or "png", dpi=120)
    plt.close(fig)


def main(args: argparse.Namespace) -> int:
    from doabench.arrays import get_array
    from doabench.recording import open_recording
    from doabench.files import atomic_path
    from doabench.trackers.registry import parse_options

    # Every output is checked before the work: none may be an input, a folder or unwritable.
    check_output_file(args.out, [args.recording, args.array], "--out")
    if args.plot:
        check_output_file(args.plot, [args.recording, args.array, args.out, args.truth], "--plot")
        check_plot_path(args.plot)
    from doabench.errors import InputError

    if args.truth:
        check_output_file(args.out, [args.truth], "--out")
        if not Path(args.truth).is_file():
            raise InputError(f"--truth {args.truth} does not exist")
    if args.vad == "truth" and not args.truth:
        raise InputError("--vad truth takes the voice activity from --truth's vad column; give --truth truth.csv")
    written: list[str] = []
    set_interrupt_note(args, lambda: f"{'wrote ' + ' and '.join(written) + ' before' if written else 'nothing was written'}"
                                     f"; a recording is tracked whole, run it again with: {command_line(args)}")
    # An untrained learned model is refused unless weights=random.
    tracker = make_checked_tracker(args.tracker, parse_options(args.tracker_opt))
    from doabench.runner import recordings
    from doabench.trackers.base import resolve_delays

    array = get_array(args.array)
    spec = tracker.frame_spec
    # Read block by block (never the whole recording): memory does not grow with its length.
    rec = open_recording(args.recording, array, spec.fs, args.resample, min_samples=spec.window)
    truth = None
    if args.truth:  # checked against the tracker's frames before the work
        n = spec.n_frames(rec.samples)
        truth = read_truth(args.truth, n, spec.times(n))
    sample_vad = None
    if args.vad == "truth":
        from doabench.framing import samples_from_frame_vad

        assert truth is not None, "main() refused --vad truth without --truth"
        if not truth["has_vad"]:
            raise InputError(f"--vad truth: {args.truth} has no vad column")
        sample_vad = samples_from_frame_vad(truth["vad"], rec.samples, spec.window, spec.hop)
    from doabench.results.writer import weights_line

    if tracker.weights_hash() or tracker.describe().get("trained") is False:  # inputs checked: say what runs
        print(f"doabench track: {args.tracker}: {weights_line(tracker.describe())}", file=sys.stderr)
    chunks, silent = recordings.recording_chunks(rec, args.vad, sample_vad=sample_vad)
    out = recordings.track_stream(tracker, array, chunks, resolve_delays(tracker, args.delays)[0], args.device)
    if silent or not out["vad"].any():
        why = ("the recording is digital silence (all samples zero)" if silent else
               "the truth's vad column has no active frame" if args.vad == "truth" else "the VAD found no speech")
        print(f"doabench track: warning: no frame was voice-active ({why}); the directions of silent frames "
              "carry no information (see the vad column)", file=sys.stderr)
    table = track_table(out)
    if truth is not None:
        from doabench.metrics import score_episode, score_frames

        # doabench run's scoring (doabench.metrics): invalid truth unscored, planar arrays folded
        planar = bool(array.planar)  # MicArray settles None (detect) to a bool
        scored = score_frames(out["directions"], truth["directions"], truth["vad"], truth["valid"], planar)
        errors = np.full(len(table), np.nan)
        errors[scored.keep] = scored.errors
        table["error_deg"] = errors
        m = score_episode(out["directions"], truth["directions"], truth["vad"], truth["valid"], planar, out["times"])
        print(score_line(args.truth, m, planar))
    with atomic_path(args.out) as tmp:
        table.to_csv(tmp, index=False, float_format="%.4f")
    written.append(args.out)
    print(f"wrote {args.out}: {len(table)} frames from {args.recording} with {args.tracker}")
    if args.plot:
        plot_track(args.plot, out["times"], out["directions"], out["vad"],
                   plot_title(args.recording, args.tracker, tracker.describe()),
                   truth=None if truth is None else truth["directions"])
        print(f"wrote {args.plot}")
    return 0
