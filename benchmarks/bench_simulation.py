"""Time to simulate one 20 s, 156-point, 12-microphone (NAO) moving-source trajectory.

Scenes come from the paper's ranges (doabench.acoustics.scenes, moving sources only): rooms from
3x3x2.5 to 10x8x6 m, T60 0.2-1.3 s, absorption weights 0.5-1, array in the lower half of the
room 10 % away from the walls. The signal is 20 s of white noise at 16 kHz (the cost does not
depend on the signal). Each backend simulates the same scenes with the same seed; the slower
backends may be run on the first few scenes only (``--pra-scenes``, ``--pra-full-scenes``,
``--torchrir-scenes``), and each one's speed-up is computed on the scenes it ran with builtin:

* ``pyroomacoustics``: pyroomacoustics' image sources up to Tdiff plus doabench's tail;
* ``pyroomacoustics-full``: pyroomacoustics for the whole response (orders of tens to hundreds
  at long T60: minutes per trajectory);
* ``torchrir``: torchrir's image sources and diffuse tail (the optional extra), on ``--device``
  like builtin.

For the builtin backend the process CPU time is also broken down by stage (the engine's
functions are wrapped with timers): image sources (``rir.render_images``), tail (level fit
``rir.tail_level`` plus noise and envelope ``rir.shared_tail``), early convolution (the
per-segment ``convolve_trajectory`` of the early parts) and tail convolution (one long FFT
convolution per microphone, ``add_tail_convolution_``); "other" is the rest (validation,
image enumeration, planning, copies).

    nice -n 10 .venv/bin/python benchmarks/bench_simulation.py --scenes 10 --pra-scenes 3 --threads 1
    nice -n 10 .venv/bin/python benchmarks/bench_simulation.py --scenes 5 --pra-scenes 5 --pra-full-scenes 5 \
        --torchrir-scenes 5 --threads 1 [--family walk]

``--duration`` shortens the trajectories (keeping 156 points per 20 s) for a quick check that
every column runs.

``--family walk`` simulates walking talkers around a turned static array (sim-walk's scene
model) and ``--family turn`` a walking talker heard by a moving, turning array (sim-turn's: one
array pose per trajectory point, so the microphones differ per point).
"""
from __future__ import annotations

import argparse
import functools
import json
import os
import time

import numpy as np
import torch

from doabench.acoustics import convolution
from doabench.acoustics import rir as engine
from doabench.acoustics.scenes import SceneDistribution, sample_scene
from doabench.acoustics.simulators import get_simulator
from doabench.errors import DependencyError
from doabench.provenance import cpu_name as _cpu_name

STAGES = {  # stage -> (module, function name)
    "image sources": [(engine, "render_images")],
    "tail": [(engine, "tail_level"), (engine, "shared_tail")],  # the names the builtin engine calls
    "early conv": [(convolution, "convolve_trajectory")],
    "tail conv": [(convolution, "add_tail_convolution_")],
}


FAMILIES = {
    "paper": {},
    "walk": {"walk_p": 1.0, "array_yaw": (-180.0, 180.0), "array_pitch": (-30.0, 30.0), "array_roll": (-15.0, 15.0)},
    "turn": {"walk_p": 1.0, "array_yaw": (-180.0, 180.0), "array_pitch": (-20.0, 20.0), "array_motion_p": 1.0,
             "array_speed": (0.0, 0.3)},
}


class StageTimer:
    """Process CPU time spent in the functions of STAGES while ``active`` (outermost calls only)."""

    def __init__(self) -> None:
        self.active = False
        self.totals = {name: 0.0 for name in STAGES}
        self._depth = 0
        for stage, targets in STAGES.items():
            for module, fname in targets:
                setattr(module, fname, self._wrap(stage, getattr(module, fname)))

    def _wrap(self, stage, fn):
        @functools.wraps(fn)
        def timed(*args, **kwargs):
            if not self.active or self._depth:
                return fn(*args, **kwargs)
            self._depth += 1
            c0 = time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                self.totals[stage] += time.process_time() - c0
                self._depth -= 1

        return timed

    def take(self) -> dict[str, float]:
        out, self.totals = self.totals, {name: 0.0 for name in STAGES}
        return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=20)
    ap.add_argument("--pra-scenes", type=int, default=20, help="scenes also run with pyroomacoustics (0: none)")
    ap.add_argument("--pra-full-scenes", type=int, default=0,
                    help="scenes also run with pyroomacoustics-full, pyroomacoustics for the whole response (0: none)")
    ap.add_argument("--torchrir-scenes", type=int, default=0, help="scenes also run with torchrir, on --device (0: none)")
    ap.add_argument("--device", default=None, help="builtin and torchrir device (cpu, cuda)")
    ap.add_argument("--duration", type=float, default=20.0,
                    help="trajectory length in seconds, 156 points per 20 s (default 20: the protocol's)")
    ap.add_argument("--threads", type=int, default=None,
                    help="threads of each backend: torch's and pyroomacoustics' num_threads (default: "
                         "each library's own; the issue's protocol is one process, one thread)")
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--family", choices=sorted(FAMILIES), default="paper",
                    help="scene model: the paper's trajectories (default), walking talkers (walk) or a walking "
                         "talker and a moving, turning array (turn)")
    ap.add_argument("--json", metavar="FILE", help="also write the per-scene times and their summary to FILE")
    args = ap.parse_args()
    if args.device and args.device.startswith("cuda") and not torch.cuda.is_available():
        ap.exit(2, f"{ap.prog}: error: --device {args.device}: CUDA is not available here\n")
    if args.threads:
        torch.set_num_threads(args.threads)
    pra_threads = None
    if args.pra_scenes > 0 or args.pra_full_scenes > 0:
        import pyroomacoustics as pra  # only when it runs: the builtin-only benchmark needs no pyroomacoustics

        if args.threads:  # its fractional-delay builder is multithreaded; same budget as torch
            pra.constants.set("num_threads", args.threads)
        pra_threads = pra.constants.get("num_threads")

    timer = StageTimer()
    n_points = max(1, int(round(156 * args.duration / 20.0)))
    dist = SceneDistribution(p_static=0.0, duration_s=args.duration, n_points=n_points, **FAMILIES[args.family])
    scenes = [sample_scene(dist, args.seed + i) for i in range(args.scenes)]
    signal = np.random.default_rng(args.seed).standard_normal(int(dist.duration_s * dist.fs)).astype(np.float32)
    limits = {"builtin": args.scenes, "pyroomacoustics": args.pra_scenes,
              "pyroomacoustics-full": args.pra_full_scenes, "torchrir": args.torchrir_scenes}
    backends = {"builtin": get_simulator("builtin", device=args.device)}
    for name in ("pyroomacoustics", "pyroomacoustics-full", "torchrir"):
        if limits[name] > 0:
            try:
                backends[name] = get_simulator(name, device=args.device if name == "torchrir" else None)
            except DependencyError as exc:  # torchrir is an optional extra
                ap.exit(2, f"{ap.prog}: error: {exc}\n")

    # warm-up (allocator, FFT plans, torchrir's sinc table) on a small problem
    sc = scenes[0]
    warm_mics = sc.mic_room_positions[:4] if sc.moving_array else sc.mic_room_positions
    for name in ("builtin", "torchrir"):
        if name in backends:
            backends[name].simulate(sc.room, sc.trajectory[:4], warm_mics, signal[:16000], dist.fs, seed=0)

    cuda = backends["builtin"].device.type == "cuda"
    times: dict[str, list[float]] = {name: [] for name in backends}
    cpu: dict[str, list[float]] = {name: [] for name in backends}  # process CPU time, all threads
    stages: list[dict[str, float]] = []
    print("wall time per trajectory (process CPU time in parentheses)")
    print(f"{'scene':>5} {'room (m)':>16} {'T60':>5} " + " ".join(f"{n:>16}" for n in backends))
    load_before = os.getloadavg()
    for i, sc in enumerate(scenes):
        mics = sc.mic_room_positions  # (M, 3), or (S, M, 3) for a moving array
        row = []
        for name, sim in backends.items():
            if i >= limits[name]:
                row.append(f"{'-':>16}")
                continue
            if sim.device.type == "cuda":
                torch.cuda.synchronize()
            timer.active = name == "builtin" and not cuda
            t0, c0 = time.perf_counter(), time.process_time()
            y = sim.simulate(sc.room, sc.trajectory, mics, signal, dist.fs, seed=sc.seed)
            dt, dc = time.perf_counter() - t0, time.process_time() - c0
            timer.active = False
            if name == "builtin" and not cuda:
                st = timer.take()
                st["other"] = dc - sum(st.values())
                stages.append(st)
            assert y.shape == (mics.shape[-2], len(signal)) and np.all(np.isfinite(y))
            times[name].append(dt)
            cpu[name].append(dc)
            row.append(f"{dt:>8.3f}s ({dc:.2f})")
        dims = "x".join(f"{d:.1f}" for d in sc.room.dims)
        print(f"{i:>5} {dims:>16} {sc.room.t60:>5.2f} " + " ".join(row), flush=True)
    load_after = os.getloadavg()

    print()
    print(f"machine: {_cpu_name()}, {os.cpu_count()} CPUs, torch {torch.__version__}, "
          f"{torch.get_num_threads()} torch threads, builtin device {backends['builtin'].device}"
          + (f", pyroomacoustics num_threads {pra_threads}" if pra_threads is not None else "")
          + (f", torchrir {backends['torchrir'].versions()['torchrir']} on {backends['torchrir'].device}"
             if "torchrir" in backends else ""))
    print(f"trajectories: {args.duration:g} s, {n_points} points, {scenes[0].mic_room_positions.shape[-2]} microphones, "
          f"family {args.family}")
    print(f"1-min load average before/after: {load_before[0]:.1f} / {load_after[0]:.1f}")
    print()
    print("| backend | scenes | mean s / trajectory | median s | min s | max s | mean CPU s |")
    print("|---|---|---|---|---|---|---|")
    for name, ts in times.items():
        t = np.array(ts)
        print(f"| {name} | {len(t)} | {t.mean():.3f} | {np.median(t):.3f} | {t.min():.3f} | {t.max():.3f} "
              f"| {np.mean(cpu[name]):.3f} |")
    for name in backends:
        if name == "builtin" or not times[name]:
            continue
        n = len(times[name])
        b, p = np.array(times["builtin"][:n]), np.array(times[name])
        bc, pc = np.array(cpu["builtin"][:n]), np.array(cpu[name])
        print(f"\n{name} / builtin on the {n} common scenes: {p.sum() / b.sum():.1f}x (total wall time), "
              f"{pc.sum() / bc.sum():.1f}x (total CPU time), median per scene {np.median(p / b):.1f}x")
    if args.json:
        summary = {name: {"scenes": len(ts), "mean_s": float(np.mean(ts)), "median_s": float(np.median(ts)),
                          "mean_cpu_s": float(np.mean(cpu[name]))} for name, ts in times.items() if ts}
        with open(args.json, "w") as f:
            json.dump({"family": args.family, "duration_s": args.duration, "n_points": n_points,
                       "device": str(backends["builtin"].device), "torch": torch.__version__,
                       "versions": {name: sim.versions() for name, sim in backends.items()},
                       "cpu": _cpu_name(), "cpus": os.cpu_count(), "threads": torch.get_num_threads(),
                       "times_s": times, "cpu_s": cpu, "summary": summary}, f, indent=1)
    if stages:
        names = list(stages[0])
        mean = {k: float(np.mean([s[k] for s in stages])) for k in names}
        total = sum(mean.values())
        print("\nbuiltin, mean process CPU s per trajectory by stage:")
        print("| " + " | ".join(names) + " | total |")
        print("|" + "---|" * (len(names) + 1))
        print("| " + " | ".join(f"{mean[k]:.3f} ({100 * mean[k] / total:.0f} %)" for k in names)
              + f" | {total:.3f} |")


if __name__ == "__main__":
    main()
