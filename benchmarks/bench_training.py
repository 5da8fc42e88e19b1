"""Training throughput of `doabench train` on this machine: where the time of one item goes, and
freshly simulated trajectories per second end to end.

Per item (process CPU time, one torch thread, so the numbers do not depend on the machine's
load): scene drawing + simulation + noise (the builtin simulator, `sim-train` scenes), feature
extraction (the tracker's features and network input) and the model's forward + backward + Adam
step per trajectory at each resolution and precision (eager float32, eager bf16 autocast,
compiled bf16 with channels-last 3D tensors). End to end: a short `Trainer` run with the
defaults `doabench train` uses (workers, precision, compile), timed over its second epoch.

    .venv/bin/python benchmarks/bench_training.py --librispeech ../shared/data/LibriSpeech \\
        --resolutions 16x32 8x16 --items 8 --e2e 16x32 --e2e-items 60
    .venv/bin/python benchmarks/bench_training.py --resolutions 32x64 --layers 32x64 --e2e 32x64 \\
        --e2e-threads 2 --e2e-items 40     # where a 32x64 step goes, and two threads end to end
    .venv/bin/python benchmarks/bench_training.py --items 10 \\
        --trackers cross3d:8x16 cross3d:4x8 gcc-cnn1d max-cnn1d:64x128 spec-cnn2d seldnet   # any learned tracker
    python3 benchmarks/bench_training.py --items 10 --trackers cross3d:16x32 --device cuda --json costs.json

With ``--device cuda`` the step is the trainer's own on the GPU, timed in wall-clock seconds with a
synchronisation (the GPU's time, not the host's); the item stays a CPU cost, as the data workers
pay it. The two give the rates that bound training: workers / item seconds, and 1 / step seconds.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
import warnings
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from doabench.provenance import cpu_name  # noqa: E402
from doabench.training.recipes import paper_recipe  # noqa: E402
from doabench.training.trainer import TrainOptions, Trainer  # noqa: E402


def per_item_costs(tracker: str, librispeech: str, n_items: int) -> dict[str, float]:
    """CPU seconds per item of simulation (scene, render, truth) and of the network input."""
    opts = TrainOptions(tracker=tracker, out=Path(tempfile.mkdtemp()), recipe=paper_recipe(), librispeech=librispeech,
                        tracker_options={"weights": "random"}, workers=0)
    trainer = Trainer(opts, log=lambda m: None)
    items, _ = trainer._epoch_items(0, (5.0, 30.0))
    simulated = items.items
    simulated[0]  # warm-up: FFT plans, speech index
    sim_s = feat_s = 0.0
    for k in range(1, n_items + 1):
        t0 = time.process_time()
        item = simulated[k]
        t1 = time.process_time()
        trainer.item_input(item["audio"], item["sample_vad"])
        t2 = time.process_time()
        sim_s, feat_s = sim_s + t1 - t0, feat_s + t2 - t1
    return {"simulation": sim_s / n_items, "features": feat_s / n_items}


def step_cost(resolution: str, precision: str, compiled: bool, batch: int, repeats: int = 3, threads: int = 1) -> float:
    """CPU seconds per trajectory of one Adam step of Cross3D on a batch of random maps; with
    ``threads`` > 1, wall-clock seconds with that many torch threads (what the step takes when the
    training process has the cores)."""
    from baselines.cross3d import Cross3D

    n_theta, n_phi = (int(v) for v in resolution.split("x"))
    torch.manual_seed(0)
    model = Cross3D(n_theta, n_phi)
    x = torch.randn(batch, 3, 103, n_theta, n_phi)
    if compiled:
        model = model.to(memory_format=torch.channels_last_3d)
        x = x.contiguous(memory_format=torch.channels_last_3d)
    forward = torch.compile(model) if compiled else model
    opt = torch.optim.Adam(model.parameters(), 1e-4)
    truth = torch.nn.functional.normalize(torch.randn(batch, 103, 3), dim=-1)

    def step() -> None:
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=precision == "bf16"):
            y = forward(x).float()
        loss = torch.nn.functional.mse_loss(y, truth)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    clock = time.process_time if threads == 1 else time.perf_counter
    torch.set_num_threads(threads)
    try:
        step()  # warm-up (and compilation)
        step()
        t0 = clock()
        for _ in range(repeats):
            step()
        return (clock() - t0) / repeats / batch
    finally:
        torch.set_num_threads(1)


def tracker_costs(tracker: str, librispeech: str, n_items: int, compiled: bool = True,
                  device: str = "cpu") -> dict[str, float]:
    """CPU seconds per trajectory of any learned tracker: the item (scene, simulation, features and
    network input, as a data worker makes it) and the trainer's own Adam step on a batch of those
    items (bf16 where the CPU has it, compiled as `doabench train`'s paper preset does), one thread.
    Run a warm-up tracker first: the first one in a process also pays the speech index and FFT plans."""
    from doabench.training.data import collate
    from doabench.training.recipes import paper_recipe

    opts = TrainOptions(tracker=tracker, out=Path(tempfile.mkdtemp()), recipe=paper_recipe(), librispeech=librispeech,
                        tracker_options={"weights": "random"}, workers=0, compile=compiled, threads=1, device=device)
    trainer = Trainer(opts, log=lambda m: None)
    items, _ = trainer._epoch_items(20, (5.0, 30.0))  # second-phase items (SNR 5-30 dB, batch 10)
    on_gpu = device.startswith("cuda")
    clock = time.perf_counter if on_gpu else time.process_time
    sync = torch.cuda.synchronize if on_gpu else (lambda: None)
    t0 = time.process_time()
    batch = collate([items[k] for k in range(n_items)])
    item_s = (time.process_time() - t0) / n_items
    repeats = 10 if on_gpu else 2
    for _ in range(2):  # warm-up (and compilation)
        trainer.train_step(batch)
    sync()
    t0 = clock()
    for _ in range(repeats):
        trainer.train_step(batch)
    sync()
    return {"item": item_s, "step": (clock() - t0) / repeats / n_items}


def layer_costs(resolution: str, batch: int = 10, frames: int = 103, repeats: int = 2) -> list[tuple[str, float]]:
    """CPU seconds per trajectory of the forward + backward of each convolution of Cross3D at
    ``resolution`` (bf16, channels-last, one thread), grouped as the network has them: where a
    training step's time goes. The step's remainder (activations, pooling, padding, Adam) is the
    compiled step minus their sum."""
    from baselines.cross3d import Cross3D

    n_theta, n_phi = (int(v) for v in resolution.split("x"))
    model = Cross3D(n_theta, n_phi)

    def conv_cost(conv: torch.nn.Module, in_shape: tuple[int, ...], grad_input: bool) -> float:
        x = torch.randn(batch, *in_shape)
        if x.dim() == 5:
            x = x.contiguous(memory_format=torch.channels_last_3d)
        x = x.bfloat16().requires_grad_(grad_input)
        layer = type(conv)(conv.in_channels, conv.out_channels, conv.kernel_size, dilation=conv.dilation).bfloat16()

        def step() -> None:
            layer(x).float().sum().backward()

        step()
        t0 = time.process_time()
        for _ in range(repeats):
            step()
        return (time.process_time() - t0) / repeats / batch

    k_t = 4  # causal padding: kernel 5 in time
    rows = [("input 3->32, 5x5x5", conv_cost(model.input.conv, (3, frames + k_t, n_theta + 4, n_phi + 4), False))]
    for level in range(model.n_layers):
        h_phi = (n_theta, n_phi >> level)
        h_theta = (n_theta >> level, n_phi)
        cost = sum(conv_cost(model.branch_phi[level].conv, (32, frames + k_t, h[0] + 2, h[1] + 2), True)
                   for h in (h_phi, h_theta))
        rows.append((f"branches, level {level + 1} ({h_phi[0]}x{h_phi[1]} and {h_theta[0]}x{h_theta[1]})", cost))
    rows.append((f"1D {model.sequence_channels}->128 and 128->3",
                 conv_cost(model.hidden.conv, (model.sequence_channels, frames + 8), True)
                 + conv_cost(model.output.conv, (128, frames + 8), True)))
    return rows


def end_to_end(tracker: str, librispeech: str, n_items: int, threads: int | None = None) -> dict[str, float]:
    """Trajectories/s over the second epoch of a short run with `doabench train`'s defaults
    (``threads``: the training process's torch threads, as ``train --threads``)."""
    from doabench.training.recipes import paper_recipe

    out = Path(tempfile.mkdtemp()) / "run"
    recipe = paper_recipe().replace(epochs=2, trajectories_per_epoch=n_items, val_trajectories=4)
    opts = TrainOptions(tracker=tracker, out=out, recipe=recipe, librispeech=librispeech, progress=False,
                        tracker_options={"weights": "random"}, compile=True, cache_root=out.parent / "cache",
                        threads=threads)
    history = Trainer(opts, log=lambda m: None).run()
    shutil.rmtree(out.parent, ignore_errors=True)
    row = history[-1]
    return {"trajectories_per_s": row["trajectories_per_s"], "epoch_s": row["epoch_s"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--librispeech", default=os.environ.get("DOABENCH_LIBRISPEECH", "../shared/data/LibriSpeech"))
    ap.add_argument("--resolutions", nargs="+", default=["16x32", "8x16"])
    ap.add_argument("--items", type=int, default=8, help="items timed for the per-item costs")
    ap.add_argument("--batch", type=int, default=10)
    ap.add_argument("--e2e", nargs="*", default=["16x32"], help="resolutions to run end to end (none: skip)")
    ap.add_argument("--e2e-items", type=int, default=60, help="trajectories per epoch of the end-to-end run")
    ap.add_argument("--e2e-threads", type=int, default=None,
                    help="torch threads of the end-to-end run's training process (default: train's, 1 beside workers)")
    ap.add_argument("--step-threads", type=int, default=1,
                    help="also time the compiled bf16 step with this many torch threads (wall-clock s)")
    ap.add_argument("--layers", nargs="*", default=[], metavar="RES",
                    help="also time each convolution of Cross3D at these resolutions (forward + backward per trajectory)")
    ap.add_argument("--trackers", nargs="*", default=[],
                    help="learned trackers whose item and compiled-step costs to time with the trainer itself "
                         "(e.g. cross3d:4x8 gcc-cnn1d max-cnn1d:64x128 spec-cnn2d seldnet); then only these")
    ap.add_argument("--device", default="cpu", help="where --trackers' steps run: cpu (default) or cuda")
    ap.add_argument("--no-compile", dest="compile", action="store_false", help="--trackers' steps uncompiled")
    ap.add_argument("--json", metavar="FILE", help="also write --trackers' costs to FILE")
    args = ap.parse_args()
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        ap.exit(2, f"{ap.prog}: error: --device {args.device}: CUDA is not available here\n")
    warnings.simplefilter("ignore")
    torch.set_num_threads(1)
    print(f"CPU: {cpu_name()}, {os.cpu_count()} cores, torch {torch.__version__}, load before {os.getloadavg()}")
    if args.trackers:
        step_name = ("compiled " if args.compile else "") + ("step GPU wall s" if args.device != "cpu" else "step CPU s")
        print(f"| tracker | item CPU s (scene, simulation, features) | {step_name} per trajectory (batch {args.items}) |")
        print("|---|---|---|")
        costs = {}
        for tracker in args.trackers:
            costs[tracker] = c = tracker_costs(tracker, args.librispeech, args.items, args.compile, args.device)
            print(f"| {tracker} | {c['item']:.3f} | {c['step']:.4f} |", flush=True)
        print(f"load after {os.getloadavg()}")
        if args.json:
            with open(args.json, "w") as f:
                json.dump({"device": args.device, "compiled": args.compile, "batch": args.items, "costs": costs}, f)
        return
    costs = per_item_costs(f"cross3d:{args.resolutions[0]}", args.librispeech, args.items)
    print(f"per item (CPU s, 1 thread): simulation {costs['simulation']:.3f}, features "
          f"({args.resolutions[0]}) {costs['features']:.3f}")
    print("| resolution | precision | step CPU s per trajectory (batch %d) |" % args.batch)
    print("|---|---|---|")
    for res in args.resolutions:
        for precision, compiled, label in (("fp32", False, "float32"), ("bf16", False, "bf16 autocast"),
                                           ("bf16", True, "bf16 autocast, compiled, channels-last")):
            print(f"| {res} | {label} | {step_cost(res, precision, compiled, args.batch):.3f} |", flush=True)
        if args.step_threads > 1:
            wall = step_cost(res, "bf16", True, args.batch, threads=args.step_threads)
            print(f"| {res} | bf16 autocast, compiled, channels-last, {args.step_threads} threads (wall s) | {wall:.3f} |",
                  flush=True)
    for res in args.layers:
        print(f"| cross3d:{res} convolution (bf16, channels-last, forward + backward) | CPU s per trajectory |")
        print("|---|---|")
        rows = layer_costs(res, args.batch)
        for name, cost in rows:
            print(f"| {name} | {cost:.3f} |", flush=True)
        print(f"| all convolutions | {sum(c for _, c in rows):.3f} |")
    for res in args.e2e:
        torch.set_num_threads(1)
        r = end_to_end(f"cross3d:{res}", args.librispeech, args.e2e_items, args.e2e_threads)
        print(f"end to end cross3d:{res} ({args.e2e_threads or 'default'} threads): {r['trajectories_per_s']:.2f} "
              f"trajectories/s (epoch of {args.e2e_items} in {r['epoch_s']:.1f} s)")
    print(f"load after {os.getloadavg()}")


if __name__ == "__main__":
    main()
