"""Per-frame latency of Cross3D streaming inference (one new SRP map in, one direction out).

    .venv/bin/python benchmarks/bench_cross3d_latency.py [--resolutions 8x16 16x32] [--threads 1 2]
        [--frames 200] [--warmup 40] [--device cuda] [--markdown] [--json FILE]

For each resolution and intra-op thread count: a randomly initialised model (latency does not
depend on the weights), ``warmup`` frames to fill the caches and warm the allocator, then
``frames`` timed ``StreamingRunner.step`` calls under ``torch.inference_mode``. Reports the median
and 90th percentile of wall-clock time and the median of the process CPU time per frame: on a
shared machine the wall clock includes time the process waited for a core, the CPU time does not
(with one thread it is what the frame costs on an idle core). For comparison, the CPU time of
the naive alternative, a full pass over the last ``receptive_field`` frames for every new frame.
A new map arrives every 192 ms; the target is 10 ms per frame at 16x32. With ``--device cuda``
the model and maps are on the GPU and every frame ends with a synchronisation, so the wall time is
what a caller waits for (launches included); the CPU time is then the host's share.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

import torch

from doabench.geometry import resolution_text
from doabench_baselines.cross3d import Cross3D
from doabench_baselines.streaming import StreamingRunner


def measure(resolution: tuple[int, int], threads: int, frames: int, warmup: int, device: str = "cpu") -> dict:
    torch.set_num_threads(threads)
    torch.manual_seed(0)
    sync = torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)
    runner = StreamingRunner(Cross3D(*resolution).to(device))
    x = torch.randn(1, 3, *resolution)
    x[:, 1:] = torch.rand(1, 2, 1, 1)  # the maximum's coordinates are constant over the map
    x = x.to(device)
    for _ in range(warmup):
        runner.step(x)
    sync()
    wall, cpu = [], []
    for _ in range(frames):
        t, c = time.perf_counter(), time.process_time()
        runner.step(x)
        sync()
        cpu.append(time.process_time() - c)
        wall.append(time.perf_counter() - t)
    # The naive alternative: recompute the whole receptive field (a full pass) for every frame.
    model = runner.model
    window = torch.randn(1, 3, model.receptive_field, *resolution, device=device)
    model(window)
    sync()
    recompute = []
    for _ in range(max(5, frames // 10)):
        c = time.process_time()
        model(window)
        sync()
        recompute.append(time.process_time() - c)
    wall.sort()
    return {
        "resolution": resolution_text(resolution),
        "device": device,
        "threads": threads,
        "wall_median_ms": 1e3 * statistics.median(wall),
        "wall_p90_ms": 1e3 * wall[int(0.9 * (len(wall) - 1))],
        "cpu_median_ms": 1e3 * statistics.median(cpu),
        "cached_frames": runner.cached_frames(),
        "recompute_cpu_median_ms": 1e3 * statistics.median(recompute),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--resolutions", nargs="+", default=["8x16", "16x32"])
    parser.add_argument("--threads", nargs="+", type=int, default=[1, 2])
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--warmup", type=int, default=40)
    parser.add_argument("--device", default="cpu", help="cpu (default) or cuda")
    parser.add_argument("--markdown", action="store_true", help="print a Markdown table")
    parser.add_argument("--json", metavar="FILE", help="also write the rows to FILE")
    args = parser.parse_args()
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        parser.exit(2, f"{parser.prog}: error: --device {args.device}: CUDA is not available here\n")
    rows = []
    with torch.inference_mode():
        for text in args.resolutions:
            n_theta, n_phi = (int(v) for v in text.lower().split("x"))
            for threads in args.threads:
                rows.append(measure((n_theta, n_phi), threads, args.frames, args.warmup, args.device))
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"# torch {torch.__version__}, {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} CPUs, load average {load:.1f}, {args.frames} frames after {args.warmup} warm-up")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"torch": torch.__version__, "load": load, "frames": args.frames, "rows": rows}, f, indent=1)
    if args.markdown:
        print("| resolution | threads | wall median (ms) | wall p90 (ms) | CPU time median (ms) "
              "| recompute-window CPU median (ms) |")
        print("|---|---|---|---|---|---|")
        for r in rows:
            print(f"| {r['resolution']} | {r['threads']} | {r['wall_median_ms']:.2f} | {r['wall_p90_ms']:.2f} "
                  f"| {r['cpu_median_ms']:.2f} | {r['recompute_cpu_median_ms']:.1f} |")
    else:
        for r in rows:
            print(f"{r['resolution']:>7}  {r['device']}  threads={r['threads']}  wall median {r['wall_median_ms']:7.2f} ms  "
                  f"p90 {r['wall_p90_ms']:7.2f} ms  cpu median {r['cpu_median_ms']:7.2f} ms  "
                  f"(recomputing the receptive field: {r['recompute_cpu_median_ms']:.1f} ms cpu)")


if __name__ == "__main__":
    main()
