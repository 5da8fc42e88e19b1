"""``doabench simulate``: draw one scene, simulate it, write audio, truth and scene description.

Outputs (written into a temporary folder next to ``--out`` that is renamed when complete):

* ``audio.wav``: ``n_mics`` channels at the scene's sample rate, 32-bit float samples exactly as
  simulated (no normalisation, no clipping);
* ``truth.csv``: one row per frame (K = 4096, hop = 3072 at 16 kHz, window-centre times):
  ``time_s, elevation_deg, azimuth_deg, x, y, z, vad`` with the direction in the array frame
  (elevation = inclination from +z) and vad 1 when more than 2/3 of the frame is voice-active;
* ``scene.json``: the scene (room, T60, SNR, array position, trajectory, speech chunk, seed), the
  distribution it was drawn from, the backend and its versions.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

from doabench.errors import ConfigError
from doabench.files import apply_umask


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "simulate", help="simulate one scene into audio.wav, truth.csv and scene.json",
        description="Draw one scene (the paper's distribution, a task's, or fixed --t60/--snr), simulate "
                    "it and write audio.wav (float32, one channel per microphone), truth.csv (per frame) "
                    "and scene.json into --out. Without LibriSpeech the embedded speech clips are used.")
    p.add_argument("--task", help="draw from this simulated task's scene distribution and speech corpus")
    p.add_argument("--t60", type=float, help="fixed reverberation time in seconds (0 = anechoic)")
    p.add_argument("--snr", type=float, help="fixed signal-to-noise ratio in dB")
    p.add_argument("--seed", type=int, default=None, help="scene seed (default 0)")
    p.add_argument("--episode", type=int, default=None,
                   help="with --task: re-create that task's episode N exactly (its seed, speech and array)")
    p.add_argument("--duration", type=float, default=None,
                   help="seconds of audio (default 20, or the task's); the trajectory keeps its points per second")
    p.add_argument("--backend", default="builtin",
                   help="room simulator: builtin, pyroomacoustics, pyroomacoustics-full, torchrir or gpurir")
    p.add_argument("--device", default=None, help="cpu or cuda (default cpu)")
    p.add_argument("--librispeech", help="LibriSpeech path (default: $DOABENCH_LIBRISPEECH, else embedded speech)")
    p.add_argument("--subset", help="LibriSpeech subset (default: the task's; without --task the only subset "
                                    "under the path, else test-clean, else test-other)")
    p.add_argument("--array", default=None, help="array name (nao) or JSON/YAML array file (default nao)")
    p.add_argument("--out", required=True, help="output folder (must not exist unless --force)")
    p.add_argument("--force", action="store_true", help="replace an existing output folder")
    p.set_defaults(func=main)


def _task_setup(task_id: str, librispeech: str | None):
    """(distribution, speech source, array name) of a simulated task."""
    from doabench.acoustics.scenes import SceneDistribution

    try:
        from doabench.envs.registry import get_task_spec
        from doabench.envs.sources import make_speech_source
    except ImportError:
        raise ConfigError("--task needs the task registry (doabench.envs.registry), which is not installed") from None
    spec = get_task_spec(task_id)
    if spec.kind != "simulated":
        raise ConfigError(f"task {spec.id!r} is a {spec.kind} task; simulate needs a simulated task")
    if "cells" in spec.params:
        raise ConfigError(f"task {spec.id!r} is a grid; simulate one of its cells (doabench list tasks)")
    # A registry may expose the parsed distribution; else the [scene] table is the distribution.
    dist = getattr(spec, "scene_distribution", None) or SceneDistribution.from_dict(dict(spec.params.get("scene", {})))
    return dist, make_speech_source(dict(spec.params.get("speech", {})), librispeech), spec.array


DEFAULT_SUBSETS = ("test-clean", "test-other")


def default_subset(root: str) -> str | None:
    """The subset to use under a LibriSpeech ``root`` when none is given: the only one there, else
    test-clean, else test-other (the official root holds several); None leaves the error to the reader."""
    from doabench.corpora.speech import resolve_librispeech
    from doabench.errors import DoabenchError

    try:
        return resolve_librispeech(root, None)[1]
    except DoabenchError:
        pass
    for name in DEFAULT_SUBSETS:
        try:
            return resolve_librispeech(root, name)[1]
        except DoabenchError:
            continue
    return None


def build_distribution(args: argparse.Namespace):
    """The scene distribution, speech source and array the arguments ask for."""
    from doabench.acoustics.scenes import SceneDistribution
    from doabench.corpora.speech import LibriSpeechSource, get_speech_source

    from doabench.corpora.paths import corpus_root

    # --librispeech or $DOABENCH_LIBRISPEECH: one path, one rule for the subset whichever way it came.
    root = corpus_root("librispeech", args.librispeech)
    if args.task:
        dist, source, array = _task_setup(args.task, root)
        if root and args.subset:
            source = LibriSpeechSource(root, args.subset)
    else:
        subset = args.subset
        if root and not subset:
            subset = default_subset(root)
        dist, source, array = SceneDistribution(), get_speech_source(root, subset), "nao"
    changes = {}
    for name, value in (("t60", args.t60), ("snr", args.snr)):
        if value is not None:
            if not math.isfinite(value):
                raise ConfigError(f"--{name} must be a finite number, got {value}")
            changes[name] = (value, value)
    if args.duration is not None:
        if not (math.isfinite(args.duration) and args.duration > 0):
            raise ConfigError(f"--duration must be a positive number of seconds, got {args.duration}")
        changes["duration_s"] = args.duration
        # Bounded so that an absurd duration reaches the memory check (check_fits) as a number.
        changes["n_points"] = max(1, round(min(dist.n_points * args.duration / dist.duration_s, 2.0**62)))
    return dist.replace(**changes) if changes else dist, source, args.array or array


def memory_fields(args: argparse.Namespace) -> dict[str, str]:
    """How the memory check (:func:`~doabench.acoustics.budget.check_fits`) names the scene's
    fields: the flags given (``--duration`` also sets the trajectory's points), else the task's."""
    from doabench.acoustics.budget import scene_fields

    fields = scene_fields(f"task {args.task!r} scene" if args.task else "scene")
    if args.t60 is not None:
        fields["t60"] = "--t60"
    if args.duration is not None:
        fields.update(duration_s="--duration", n_points="--duration")
    return fields


def _task_episode(args: argparse.Namespace):
    """(scene, speech source, distribution) of episode ``--episode`` of ``--task``, exactly as the
    task's episode source draws it (``doabench run`` sees the same scene)."""
    if not args.task:
        raise ConfigError("--episode needs --task")
    clashes = [f"--{n}" for n in ("seed", "t60", "snr", "duration", "array") if getattr(args, n) is not None]
    if clashes:
        raise ConfigError(f"--episode re-creates a task episode; drop {', '.join(clashes)}")
    try:
        from doabench.envs.registry import get_task_spec
        from doabench.envs.simulated import SimulatedEpisodes
        from doabench.envs.sources import make_episode_source
    except ImportError:
        raise ConfigError("--task needs the task registry (doabench.envs), which is not installed") from None
    spec = get_task_spec(args.task)
    if spec.kind != "simulated":
        raise ConfigError(f"task {spec.id!r} is a {spec.kind} task; simulate needs a simulated task")
    source = make_episode_source(spec, librispeech=args.librispeech, backend=args.backend, device=args.device)
    if not isinstance(source, SimulatedEpisodes):  # a plug-in replacing the simulated kind
        raise ConfigError(f"task {spec.id!r}: its episode source draws no scenes for simulate to write")
    if not 0 <= args.episode < len(source):
        raise ConfigError(f"task {spec.id!r} has {len(source)} episodes; --episode must be in 0..{len(source) - 1}")
    return source.scene(args.episode), source.speech, None


def write_outputs(folder: Path, episode, scene_info: dict) -> None:
    """Write audio.wav, truth.csv and scene.json into ``folder``."""
    from doabench.framing import FrameSpec
    from doabench.recording import float_wav_bytes
    from doabench.files import atomic_path, write_text

    with atomic_path(folder / "audio.wav") as tmp:
        tmp.write_bytes(float_wav_bytes(episode.audio, episode.fs))
    frames = FrameSpec(fs=episode.fs)
    truth = episode.frame_truth(frames)
    with atomic_path(folder / "truth.csv") as tmp, open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["time_s", "elevation_deg", "azimuth_deg", "x", "y", "z", "vad"])
        for t, el, az, d, v in zip(truth["times"], np.degrees(truth["elevation"]), np.degrees(truth["azimuth"]),
                                   truth["directions"], truth["vad"]):
            w.writerow([f"{t:.6f}", f"{el:.4f}", f"{az:.4f}", f"{d[0]:.6f}", f"{d[1]:.6f}", f"{d[2]:.6f}", int(v)])
    info = dict(scene_info, frames=frames.to_dict(),
                audio={"file": "audio.wav", "fs": episode.fs, "channels": episode.n_mics, "subtype": "FLOAT"})
    write_text(folder / "scene.json", json.dumps(info, indent=1) + "\n")


SIMULATE_FILES = frozenset({"audio.wav", "truth.csv", "scene.json"})


def _written_by_simulate(folder: Path) -> bool:
    """True when ``folder`` holds only what an earlier ``simulate`` wrote (its three files, with a
    scene.json that simulate made)."""
    try:
        names = {p.name for p in folder.iterdir()}
        if not names or not names <= SIMULATE_FILES or "scene.json" not in names:
            return False
        if any(not (folder / n).is_file() or (folder / n).is_symlink() for n in names):
            return False
        info = json.loads((folder / "scene.json").read_text())
    except (OSError, ValueError, UnicodeDecodeError):
        return False
    return isinstance(info, dict) and "doabench_version" in info and isinstance(info.get("audio"), dict)


def check_out(out: Path, force: bool) -> None:
    """Refuse an ``--out`` that simulate must not write or replace, before any work is done.

    It must name a folder of its own (not ``.``, a parent of the working folder or ``/``); an existing
    one is replaced only with ``--force`` and only when an earlier ``simulate`` wrote it; anything
    else (a user's file, a folder of other files) is never deleted."""
    resolved = out.expanduser().resolve()
    cwd = Path.cwd().resolve()
    if not resolved.name or resolved == cwd or resolved in cwd.parents:
        raise ConfigError(f"--out {out} is the working folder or one of its parents; name a new folder for "
                          "the outputs, e.g. --out sim1")
    if out.is_symlink() or (out.exists() and not out.is_dir()):
        raise ConfigError(f"--out {out} exists and is not a folder; it is never replaced (pick another --out)")
    if not out.exists() or not any(out.iterdir()):
        return
    if not force:
        raise ConfigError(f"output folder {out} already exists; use --force to replace it")
    if not _written_by_simulate(out):
        raise ConfigError(f"output folder {out} holds files simulate did not write; --force replaces only a "
                          "folder an earlier simulate wrote (audio.wav, truth.csv, scene.json)")


def _publish(tmp: Path, out: Path, force: bool) -> None:
    """Move the finished ``tmp`` folder to ``out`` (replacing it only with ``force``, and only
    when an earlier simulate wrote it)."""
    check_out(out, force)  # again: the folder may have changed during the simulation
    if out.exists():
        if not any(out.iterdir()):
            out.rmdir()
        else:
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
            out.replace(old / out.name)
            tmp.replace(out)
            shutil.rmtree(old, ignore_errors=True)
            return
    tmp.replace(out)


def main(args: argparse.Namespace) -> int:
    from doabench._version import __version__
    from doabench.acoustics.budget import check_fits, drawn_scene_note
    from doabench.acoustics.render import render_scene
    from doabench.acoustics.scenes import sample_scene
    from doabench.acoustics.simulators import get_simulator
    from doabench.arrays import get_array

    out = Path(args.out)
    check_out(out, args.force)
    simulator = get_simulator(args.backend, device=args.device)
    if args.episode is not None:
        scene, source, dist = _task_episode(args)
        array = scene.array
    else:
        seed = 0 if args.seed is None else args.seed
        if seed < 0:
            raise ConfigError(f"--seed must be >= 0, got {seed}")
        dist, source, array_name = build_distribution(args)
        array = get_array(array_name)
        check_fits(dist, array.n_mics, memory_fields(args), simulator.name)  # before the scene is drawn
        scene = sample_scene(dist, seed, source, array=array)
    if note := drawn_scene_note(scene, simulator.name, args.device):  # a slow engine says so before it starts
        print(note, file=sys.stderr, flush=True)
    episode = render_scene(scene, source, array, simulator=simulator, device=args.device)
    meta = episode.metadata
    info = {"doabench_version": __version__, "task": args.task, "episode": args.episode, "seed": scene.seed,
            **meta, "distribution": None if dist is None else dist.to_dict(), "array": array.to_dict()}

    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    try:
        write_outputs(tmp, episode, info)
        apply_umask(tmp, folder=True)  # mkdtemp makes it 0700 whatever the umask
        _publish(tmp, out, args.force)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    kind = "static" if scene.static else "moving"
    print(f"wrote {out}{os.sep}: audio.wav ({episode.n_mics} ch, {episode.n_samples / episode.fs:g} s, float32), "
          f"truth.csv, scene.json | room {'x'.join(f'{d:.2f}' for d in scene.room.dims)} m, "
          f"T60 {scene.room.t60:.2f} s, SNR {scene.snr_db:.1f} dB, {kind} source, {meta['backend']} backend, "
          f"{scene.speech['corpus']} speech"
          + (f" (subset {scene.speech['subset']})" if scene.speech.get("subset") else ""))
    return 0
