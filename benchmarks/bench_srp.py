"""SRP-PHAT map throughput: doabench (nearest and exact delays) vs pyroomacoustics' SRP.

20 s of 12-channel 16 kHz white noise on the NAO array (103 frames of K = 4096, hop 3072) ->
SRP-PHAT maps at 4x8 ... 64x128. doabench is timed end to end (audio -> STFT -> PHAT -> GCC ->
normalised maps) with :class:`doabench.features.SRPPHAT`, built once outside the timing (its
delay tables are precomputed at construction); median of ``--runs`` runs after one warm-up run.
pyroomacoustics' ``doa.algorithms["SRP"]`` (dim=3, the same grid as azimuth/colatitude, all
K/2 + 1 bins) gets the same windowed spectra one frame per ``locate_sources`` call; it is timed on
``--pra-frames`` frames and scaled to all frames (its cost is the same for every frame).

    .venv/bin/python benchmarks/bench_srp.py            # full table (pyroomacoustics takes minutes)
    .venv/bin/python benchmarks/bench_srp.py --quick    # doabench only, 3 runs

Not a test: numbers depend on the machine and its load; the load average is printed with them.
"""
from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np
import torch

from doabench.provenance import cpu_name
from doabench.arrays import get_array
from doabench.geometry import resolution_text
from doabench.features import SRPPHAT
from doabench.features import functional as F
from doabench.framing import FrameSpec
from doabench.geometry import grid_angles

RESOLUTIONS = ((4, 8), (8, 16), (16, 32), (32, 64), (64, 128))




def time_call(fn, runs: int, budget_s: float) -> tuple[float, float, int]:
    """Median wall and process-CPU seconds of ``fn()`` over ``runs`` runs after one warm-up
    (fewer runs if they would take longer than ``budget_s``)."""
    t0 = time.perf_counter()
    fn()
    first = time.perf_counter() - t0
    runs = max(1, min(runs, int(budget_s / max(first, 1e-9))))
    wall, cpu = [], []
    for _ in range(runs):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return statistics.median(wall), statistics.median(cpu), runs


def pra_time(positions: np.ndarray, spectra: np.ndarray, res, fs: int, window: int, n_frames: int):
    """Wall and CPU seconds per frame of pyroomacoustics SRP, and its argmax grid indices."""
    import pyroomacoustics as pra

    el, az = grid_angles(*res)
    doa = pra.doa.algorithms["SRP"](
        L=positions.T, fs=fs, nfft=window, c=343.0, num_src=1, dim=3, azimuth=az, colatitude=el
    )
    bins = np.arange(window // 2 + 1)
    peaks = []
    t0, c0 = time.perf_counter(), time.process_time()
    for t in range(n_frames):
        doa.locate_sources(spectra[t][:, :, None], freq_bins=bins)
        peaks.append(int(np.argmax(doa.grid.values)))
    return (time.perf_counter() - t0) / n_frames, (time.process_time() - c0) / n_frames, peaks


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--runs", type=int, default=7, help="timed runs per configuration (after a warm-up)")
    parser.add_argument("--budget", type=float, default=30.0, help="max seconds of timed runs per configuration")
    parser.add_argument("--pra-frames", type=int, default=None, help="frames pyroomacoustics is timed on (default: 3, 1 above 16x32)")
    parser.add_argument("--quick", action="store_true", help="doabench only, 3 runs")
    parser.add_argument("--no-pra", action="store_true", help="skip pyroomacoustics")
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's default)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    runs = 3 if args.quick else args.runs

    array = get_array("nao")
    spec = FrameSpec()
    rng = np.random.default_rng(0)
    audio = torch.from_numpy(rng.standard_normal((1, array.n_mics, int(args.seconds * spec.fs))).astype(np.float32))
    n_frames = spec.n_frames(audio.shape[-1])
    spectra = F.stft_frames(audio.double(), spec.window, spec.hop)[0].numpy()  # (T, M, F) for pra

    print(f"machine: {cpu_name()}, {os.cpu_count()} CPUs, torch {torch.__version__} with {torch.get_num_threads()} threads")
    print(f"load average at start: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
    print(f"input: {args.seconds:g} s, {array.n_mics} mics, {spec.fs} Hz -> {n_frames} frames of {spec.window} (hop {spec.hop})")
    header = (
        f"{'grid':>7} | {'nearest s':>9} | {'(cpu s)':>7} | {'maps/s':>7} | {'exact s':>8} | {'(cpu s)':>7} | "
        f"{'pra s (scaled)':>14} | {'pra/nearest':>11} | {'pra/exact':>9} | argmax pra==exact"
    )
    print(header)
    print("-" * len(header))
    rows = []
    for res in RESOLUTIONS:
        row = {"res": resolution_text(res)}
        maps = {}
        for mode in ("nearest", "exact"):
            srp = SRPPHAT(array, res, spec, mode)
            with torch.inference_mode():
                row[mode], row[mode + "_cpu"], row[mode + "_runs"] = time_call(lambda: srp(audio), runs, args.budget)
                maps[mode] = srp(audio)[0]
        if not (args.quick or args.no_pra):
            n_pra = args.pra_frames or (3 if res[0] * res[1] <= 512 else 1)
            per_frame, cpu_per_frame, peaks = pra_time(array.positions, spectra, res, spec.fs, spec.window, n_pra)
            row["pra"] = per_frame * n_frames
            row["pra_cpu"] = cpu_per_frame * n_frames
            ours = maps["exact"][:n_pra].flatten(1).argmax(1).tolist()
            row["agree"] = f"{sum(a == b for a, b in zip(peaks, ours))}/{n_pra}"
            row["pra_frames"] = n_pra
        pra_s = f"{row['pra']:.1f} ({row['pra_frames']} fr)" if "pra" in row else "-"
        ratio_n = f"{row['pra'] / row['nearest']:.0f}x" if "pra" in row else "-"
        ratio_e = f"{row['pra'] / row['exact']:.0f}x" if "pra" in row else "-"
        print(
            f"{row['res']:>7} | {row['nearest']:9.4f} | {row['nearest_cpu']:7.4f} | {n_frames / row['nearest']:7.0f} | "
            f"{row['exact']:8.3f} | {row['exact_cpu']:7.3f} | "
            f"{pra_s:>14} | {ratio_n:>11} | {ratio_e:>9} | {row.get('agree', '-')}",
            flush=True,
        )
        rows.append(row)
    if any("pra" in r for r in rows):
        print("CPU-time ratios pra/nearest: " + ", ".join(f"{r['res']} {r['pra_cpu'] / r['nearest_cpu']:.0f}x" for r in rows if "pra" in r))
    print("(cpu s: process CPU time of the same call, all threads; runs: "
          + ", ".join(f"{r['res']} {r['nearest_runs']}/{r['exact_runs']}" for r in rows) + " nearest/exact)")
    print(f"load average at end: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
    target = next(r for r in rows if r["res"] == "16x32")
    print(
        f"targets at 16x32: nearest {target['nearest']:.4f} s for {n_frames} maps (target <= 0.1 s)"
        + (f"; {target['pra'] / target['nearest']:.0f}x faster than pyroomacoustics (target >= 1000x)" if "pra" in target else "")
    )


if __name__ == "__main__":
    main()
