#!/usr/bin/env bash
# Every CUDA path of doabench, checked and timed in one run on a machine with an NVIDIA GPU.
#
# It installs doabench into the machine's Python (with the wheels in .whl/ when the machine has no
# package index), then, each stage under its own time limit and all under GPU_CHECK_BUDGET_S:
#   (a) the CUDA tests (tests/test_cuda.py: simulator, SRP-PHAT, Cross3D and training against the
#       CPU; tests/test_engines.py: builtin and torchrir on cuda) first, and last `pytest -m "not slow"` on the rest, in parallel over the machine's cores,
#       with what the budget leaves;
#   (b) `doabench train --device cuda --preset paper` for cross3d:16x32 on a fixed number of freshly
#       simulated trajectories, data workers on all cores but one, with nvidia-smi sampled, and the
#       two rates that bound it (workers / item CPU s, 1 / GPU step s: benchmarks/bench_training.py),
#       for cross3d:32x64 too, with the hours the paper's schedule (80 x 585 trajectories) would take
#       at the lower of its two rates;
#   (c) benchmarks/bench_simulation.py and benchmarks/bench_cross3d_latency.py on cuda (and the
#       simulation on one CPU thread, for the ratio; and torchrir against builtin on cuda where
#       torchrir is installed);
#   (d) `doabench run --device cuda` and `--device cpu` on sim-demo with cross3d:16x32, and how far
#       apart the two results are.
# Speech comes from a LibriSpeech-layout folder of the embedded clips (doabench.corpora.fixture):
# the machine needs no corpus, and a trajectory costs the same whatever it says.
# Output: $OUT/gpu_check.log (everything, as it goes), $OUT/figures.json (the figures),
# $OUT/nvidia-smi.csv (samples during training), $OUT/train_log.csv.
#
#   OUT=runs/gpu-check GPU_CHECK_BUDGET_S=420 bash benchmarks/gpu_check.sh
#   GPU_CHECK_TRAJECTORIES=500 GPU_CHECK_EPOCHS=2 ...   # the training stage's size (these defaults)
#   GPU_CHECK_ONLY="install-wheels install pytest-cuda run-cuda run-cpu" ...   # a rerun of some stages
set -uo pipefail
cd "$(dirname "$0")/.."
OUT="${OUT:-runs/gpu-check}"
BUDGET="${GPU_CHECK_BUDGET_S:-420}"
EPOCHS="${GPU_CHECK_EPOCHS:-2}"
TRAJECTORIES="${GPU_CHECK_TRAJECTORIES:-500}"
PY="${PYTHON:-python3}"
ONLY="${GPU_CHECK_ONLY:-}"  # stage names to run (others skipped), e.g. "pytest-cuda run-cuda run-cpu"
for v in BUDGET EPOCHS TRAJECTORIES; do
    [[ "${!v}" =~ ^[0-9]+$ ]] || { echo "gpu_check: ${v} must be a whole number, got '${!v}'" >&2; exit 2; }
done
mkdir -p "$OUT"
WORK="$(mktemp -d)"
LOG="$OUT/gpu_check.log"
: > "$LOG"
export PYTHONUNBUFFERED=1 MPLBACKEND=Agg
START=$(date +%s)
say() { echo "$*" | tee -a "$LOG"; }
left() { echo $(( BUDGET - ($(date +%s) - START) )); }

# stage NAME CAP_S COMMAND...: runs COMMAND under min(CAP_S, budget left), output to the log as it
# comes; records "NAME rc seconds" in $WORK/stages.txt (rc 124: stopped at its limit).
stage() {
    local name=$1 cap=$2 rest t0 rc
    shift 2
    if [ -n "$ONLY" ] && [[ " $ONLY " != *" $name "* ]]; then
        return
    fi
    rest=$(left)
    if [ "$rest" -lt 15 ]; then
        say "== $name: skipped, the budget is spent"
        echo "$name skipped 0" >> "$WORK/stages.txt"
        return
    fi
    [ "$cap" -gt "$rest" ] && cap=$rest
    say "== $name (at most ${cap} s, $(( $(date +%s) - START )) s in)"
    t0=$(date +%s)
    timeout --kill-after=10 "$cap" "$@" 2>&1 | tee -a "$LOG"
    rc=${PIPESTATUS[0]}
    say "== $name: rc $rc in $(( $(date +%s) - t0 )) s"
    echo "$name $rc $(( $(date +%s) - t0 ))" >> "$WORK/stages.txt"
}

say "== machine: $(nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>&1), $(nproc) cores"
if [ -d .whl ] && compgen -G ".whl/*.whl" > /dev/null; then
    stage install-wheels 120 "$PY" -m pip install -q --no-index --no-deps --no-compile --disable-pip-version-check .whl/*.whl
fi
stage install 120 "$PY" -m pip install -q --no-index --no-deps --no-build-isolation --disable-pip-version-check -e .
say "$("$PY" -c 'import torch, doabench; print("torch", torch.__version__, "cuda", torch.version.cuda, "available", torch.cuda.is_available(), "doabench", doabench.__version__)' 2>&1)"
FIXTURE="$WORK/LibriSpeech"
"$PY" -c "from doabench.corpora.fixture import write_librispeech_layout as w; w('$FIXTURE', speakers=20)" 2>&1 | tee -a "$LOG"

# (a) tests
stage pytest-cuda 150 "$PY" -m pytest -p no:cacheprovider -m cuda -v -rs tests/test_cuda.py tests/test_engines.py

# (b) training on the GPU, data workers on the CPU cores
stage train-costs 90 "$PY" benchmarks/bench_training.py --librispeech "$FIXTURE" --items 10 --trackers cross3d:16x32 \
    --device cuda --no-compile --json "$WORK/train_costs.json"
nvidia-smi --query-gpu=timestamp,utilization.gpu,memory.used --format=csv,noheader,nounits -lms 500 \
    > "$OUT/nvidia-smi.csv" 2>/dev/null &
SMI=$!
date +%s.%N > "$WORK/train_start"
stage train 240 "$PY" -m doabench train --tracker cross3d:16x32 --tracker-opt weights=random --preset paper \
    --device cuda --epochs "$EPOCHS" --epoch-size "$TRAJECTORIES" --val-trajectories 20 --workers "$(( $(nproc) - 1 ))" \
    --no-compile --librispeech "$FIXTURE" --cache-root "$WORK/cache" --out "$WORK/train" --quiet
kill "$SMI" 2>/dev/null
cp "$WORK/train/log.csv" "$OUT/train_log.csv" 2>/dev/null

# (c) simulation and streaming latency
stage bench-simulation-cuda 60 "$PY" benchmarks/bench_simulation.py --device cuda --scenes 10 --pra-scenes 0 \
    --json "$WORK/sim_cuda.json"
stage bench-simulation-cuda-turn 60 "$PY" benchmarks/bench_simulation.py --device cuda --scenes 10 --pra-scenes 0 \
    --family turn --json "$WORK/sim_cuda_turn.json"
stage bench-simulation-cpu 60 "$PY" benchmarks/bench_simulation.py --device cpu --threads 1 --scenes 10 \
    --pra-scenes 0 --json "$WORK/sim_cpu.json"
# torchrir (the optional extra; its wheel in .whl/ where the machine has no package index) and the
# builtin engine on the same scenes, both on cuda
if "$PY" -c "import torchrir" 2>/dev/null; then
    stage bench-simulation-torchrir-cuda 90 "$PY" benchmarks/bench_simulation.py --device cuda --scenes 5 \
        --pra-scenes 0 --torchrir-scenes 5 --json "$WORK/sim_torchrir_cuda.json"
else
    say "== bench-simulation-torchrir-cuda: skipped, torchrir is not installed (pip install \"doabench[torchrir]\")"
fi
stage bench-latency-cuda 60 "$PY" benchmarks/bench_cross3d_latency.py --device cuda --threads 1 --frames 200 \
    --json "$WORK/latency_cuda.json"

# (d) a scored run on cuda against the same run on the CPU
stage run-cuda 90 "$PY" -m doabench run --tracker cross3d:16x32 --task sim-demo --device cuda --out "$WORK/run-cuda" --quiet
stage run-cpu 90 "$PY" -m doabench run --tracker cross3d:16x32 --task sim-demo --device cpu --out "$WORK/run-cpu" --quiet

# (b, the rest) the paper's finer maps: what a cross3d:32x64 run would cost here
stage train-costs-32x64 90 "$PY" benchmarks/bench_training.py --librispeech "$FIXTURE" --items 10 \
    --trackers cross3d:32x64 --device cuda --no-compile --json "$WORK/train_costs_32x64.json"

# (a, the rest) the suite without the slow tests, with what the budget leaves
workers=$(( $(nproc) > 2 ? $(nproc) - 2 : 1 ))
stage pytest-not-slow 240 "$PY" -m pytest -p no:cacheprovider -m "not slow and not cuda" -rfE -n "$workers" -v \
    | grep -E --line-buffered "FAILED|ERROR|passed|failed|^E "

"$PY" - "$WORK" "$OUT" <<'EOF' 2>&1 | tee -a "$LOG"
"""Collect the stages' figures into $OUT/figures.json and print them."""
import csv
import json
import sys
from pathlib import Path

import numpy as np

work, out = Path(sys.argv[1]), Path(sys.argv[2])
figures = {"stages": {}}
stages = work / "stages.txt"
for line in (stages.read_text().splitlines() if stages.is_file() else []):
    name, rc, seconds = line.split()
    figures["stages"][name] = {"rc": rc, "seconds": int(seconds)}


def load(name):
    path = work / name
    return json.loads(path.read_text()) if path.is_file() else None


try:
    import torch
    figures["gpu"] = torch.cuda.get_device_name(0) if torch.cuda.is_available() else None
    figures["torch"] = torch.__version__
except Exception as exc:  # the figures are still written
    figures["gpu"] = f"unknown ({exc})"
costs = load("train_costs.json")
log = out / "train_log.csv"
if log.is_file():
    rows = list(csv.DictReader(log.open()))
    figures["train"] = {"epochs": [{"epoch": int(r["epoch"]), "trajectories_per_s": float(r["trajectories_per_s"]),
                                    "epoch_s": float(r["epoch_s"])} for r in rows]}
    start = float((work / "train_start").read_text())
    util = []
    for row in csv.reader((out / "nvidia-smi.csv").open()):
        try:
            util.append((float(row[1]), float(row[2])))
        except (ValueError, IndexError):
            continue
    if util:
        u = np.array(util)
        figures["train"]["gpu_utilisation_mean_pct"] = float(u[:, 0].mean())
        figures["train"]["gpu_utilisation_busy_share"] = float((u[:, 0] > 0).mean())
        figures["train"]["gpu_memory_max_mib"] = float(u[:, 1].max())
    if costs and rows:
        import os
        c = costs["costs"]["cross3d:16x32"]
        workers = (os.cpu_count() or 2) - 1
        rate = figures["train"]["epochs"][-1]["trajectories_per_s"]
        bound = {"workers_rate": workers / c["item"], "gpu_rate": 1.0 / c["step"], "measured_rate": rate,
                 "item_cpu_s": c["item"], "gpu_step_s_per_trajectory": c["step"], "workers": workers}
        bound["bound_by"] = "data workers (simulation + features)" if bound["workers_rate"] < bound["gpu_rate"] else "GPU step"
        figures["train"]["bound"] = bound
finer = load("train_costs_32x64.json")
if costs or finer:  # per tracker: what would bound a run on this machine, and the paper's schedule at that rate
    import os

    from doabench.training.recipes import paper_recipe

    paper = paper_recipe()
    workers = (os.cpu_count() or 2) - 1
    figures["train_bounds"] = {}
    for tracker, c in {**(costs or {}).get("costs", {}), **(finer or {}).get("costs", {})}.items():
        rate = min(workers / c["item"], 1.0 / c["step"])
        figures["train_bounds"][tracker] = {
            "workers_rate": workers / c["item"], "gpu_rate": 1.0 / c["step"], "bound_rate": rate,
            "paper_schedule_h": paper.epochs * paper.trajectories_per_epoch / rate / 3600}
sims = {k: load(f"sim_{k}.json") for k in ("cuda", "cuda_turn", "cpu")}
figures["simulation"] = {k: v["summary"]["builtin"] for k, v in sims.items() if v}
torchrir_sim = load("sim_torchrir_cuda.json")
if torchrir_sim:  # builtin and torchrir on the same scenes, on cuda
    figures["simulation_torchrir_cuda"] = torchrir_sim["summary"]
lat = load("latency_cuda.json")
if lat:
    figures["latency_cuda"] = [{k: r[k] for k in ("resolution", "wall_median_ms", "wall_p90_ms")} for r in lat["rows"]]
runs = {d: next((work / f"run-{d}").glob("*.json"), None) for d in ("cuda", "cpu")}
if all(runs.values()):
    gpu, cpu = (json.loads(runs[d].read_text()) for d in ("cuda", "cpu"))
    diffs = []
    for fg, fc in zip(gpu["frames"], cpu["frames"]):
        a, b = np.asarray(fg["estimates"], float), np.asarray(fc["estimates"], float)
        a /= np.linalg.norm(a, axis=1, keepdims=True)
        b /= np.linalg.norm(b, axis=1, keepdims=True)
        diffs.append(np.degrees(np.arccos(np.clip((a * b).sum(1), -1, 1))))
    d = np.concatenate(diffs)
    figures["run_sim_demo"] = {
        "rmsae_all": {"cuda": gpu["summary"]["rmsae_all"], "cpu": cpu["summary"]["rmsae_all"]},
        "rmsae_nonsilent": {"cuda": gpu["summary"]["rmsae_nonsilent"], "cpu": cpu["summary"]["rmsae_nonsilent"]},
        "frame_difference_deg": {"median": float(np.median(d)), "max": float(d.max()),
                                 "share_over_1deg": float((d > 1).mean())},
        "wall_time_s": {"cuda": gpu["wall_time_s"], "cpu": cpu["wall_time_s"]},
    }
(out / "figures.json").write_text(json.dumps(figures, indent=1))
print(json.dumps(figures, indent=1))
EOF
rm -rf "$WORK"
say "== done in $(( $(date +%s) - START )) s"
