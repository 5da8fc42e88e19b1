#!/usr/bin/env bash
# Maintainers: train every shipped learned tracker in turn (the training queue), resuming and exporting each.
# The order: Cross3D 16x32, 8x16, 4x8, gcc-cnn1d, max-cnn1d (64x128 maxima), then seldnet before spec-cnn2d (seldnet is 3x cheaper
# per trajectory, and spec-cnn2d's recipe is under review: see docs/training.md), all with `doabench train`'s paper
# preset on sim-train (an entry may name another preset, e.g. finetune, which starts from the
# tracker's shipped weights instead of weights=random). Each run resumes from
# training-runs/<name>/ (the committed run state); a finished run is exported to
# baselines/weights/<weights>.safetensors (SHA256SUMS updated), its checkpoint is deleted
# (log.csv, loss.png and config.json stay as the record) and training-runs/<name>/exported.txt
# says so. Stop it at any time (Ctrl-C, kill) and run it again to continue where it stopped;
# commit training-runs/ (and baselines/weights/) before the machine is needed back
# (scripts/commit_run_state.sh).
#
# Runs whose state is too large to commit mid-run (the 1D CNNs: 70-110 MB compact, against the
# 150 MB that run states may add to the repository in all) must finish within the run of the queue
# that starts them. With QUEUE_DEADLINE (Unix time by which the training must stop) such an entry
# is started only when its estimated hours fit before the deadline; otherwise it is deferred to a
# later run of the queue, which goes on with the entries that may be stopped and resumed. Without
# QUEUE_DEADLINE every entry runs in order.
#
#   QUEUE_DEADLINE=$(( $(date +%s) + 165 * 60 )) nice -n 10 scripts/train_queue.sh   # free for 3 hours
#   DOABENCH_LIBRISPEECH=/data/LibriSpeech nice -n 10 scripts/train_queue.sh
set -euo pipefail
cd "$(dirname "$0")/.."
LIBRI="${DOABENCH_LIBRISPEECH:-../shared/data/LibriSpeech}"
DOABENCH="${DOABENCH:-.venv/bin/doabench}"
PYTHON="${PYTHON:-.venv/bin/python}"
DEADLINE="${QUEUE_DEADLINE:-}"
if [ -n "$DEADLINE" ] && ! [[ "$DEADLINE" =~ ^[0-9]+$ ]]; then
    echo "QUEUE_DEADLINE must be a Unix time in seconds (e.g. \$(( \$(date +%s) + 165 * 60 ))), got '$DEADLINE'" >&2
    exit 2
fi
# tracker, preset, run name, weights file name, stored dtype of the exported weights, uninterrupted
# hours, torch threads of the training process, then any extra `doabench train` recipe options.
# Stored dtype: float16 for the 1D CNNs (11.3 M and 6.9 M parameters: 23 and 14 MB in the
# repository instead of 45 and 28; loaded back as float32, outputs within 0.01 deg, see
# docs/results.md), float32 for the rest. Uninterrupted hours: 0 for a run whose
# state is small enough to commit at every stop, else the hours it needs from start to
# export. Threads (kept when a run resumes, unlike the recipe options): 1 where the data workers
# are the bottleneck (they use the other core); 2 for spec-cnn2d, whose model step takes ~5x its
# item (0.90 vs 0.19 CPU s) so its one worker idles most of the time: 2 threads made that step
# 1.42x faster in wall time with a training run beside it (docs/training.md). Costs per trajectory (item,
# step) in docs/training.md ("The training queue and the run-state budget", from
# benchmarks/bench_training.py --trackers): the 1D CNNs cost about what cross3d:8x16 does, whose
# run did 5.8 trajectories/s on an AMD EPYC (about 2.2 h for 46,800; the budget keeps a
# margin). spec-cnn2d and seldnet are step-bound (0.90 and 0.26 CPU-s) and train on T60 0-0.3 s
# (the trainer's default for them) for 18 epochs, 10,530 trajectories (the paper's >= 10,000;
# second phase from epoch 9); their states (1.9 M and 0.1 M parameters) may be committed at every
# stop.
# A threads field "B/F" means B threads where the CPU trains in bf16 (native bf16: the data workers
# are the bottleneck) and F where it trains in fp32 (no native bf16, e.g. an AVX2-only AMD EPYC):
# there Cross3D 16x32's fp32 step costs ~2.1 CPU-s per trajectory against ~0.8 for its item, so with
# one thread the second core idled ~2/3 of the time; 2 threads took the run from 0.467 to 0.65-0.69
# trajectories/s (docs/training.md).
# The paper preset trains from scratch (weights=random), finetune starts from shipped weights.
# cross3d-16x32-v3: the shipped Cross3D 16x32 trained on sim-train v1 (talkers walk on
# through their pauses), every other model on v3; the same recipe on v3 says whether the v3 data
# changes the 16x32 model's sim-grid score. It exports beside the v1 model
# (cross3d-16x32-v3.safetensors, used with --tracker-opt weights=FILE) and replaces it as the
# default only if it scores better (docs/results.md).
# cross3d-16x32-moving and cross3d-8x16-moving: the paper recipe on sim-train-moving (the paper's
# trajectories mixed with walking talkers, turned and moving arrays), so that Cross3D keeps up with
# a walking talker; they export beside the shipped models (weights=FILE) and become the default
# only where they meet the moving-talker targets of docs/results.md.
# cross3d-16x32-moving-long: the 16x32 moving model trained on: the paper's schedule (80 epochs, its
# learning rates) restarted from its weights (an entry whose options name the weights starts from them;
# a paper entry otherwise starts from random weights), since the 32x64 maps did not lead on 18 epochs.
# It was stopped after epoch 65 of 80 and exported (training-runs/cross3d-16x32-moving-long/card.md:
# its best epoch by the held RMSAE, 24, was not beaten after it).
# cross3d-32x64-moving: the same on the paper's finer 32x64 maps. Its step is step-bound (1.29 CPU-s
# per trajectory compiled in bf16 against a 0.34 s item, benchmarks/bench_training.py), so the
# training process takes both cores (2 threads) and the data worker fills the gaps. Its schedule is
# shortened to 18 epochs, the switch at epoch 10: the paper's 80 take about 12 h of these cores and
# more run-state commits than a round allows, and the 16x32 moving run made most of its gain after
# epoch 10 in the first epoch of its second phase (validation, voice-active: 13.32 -> 11.74 deg; its
# last 59 epochs added 0.8 deg).
# cross3d-32x64-moving-long: 32x64 maps on the paper's full schedule (80 epochs, switch at 20) on
# sim-train-moving, warm-started from cross3d-16x32-moving-long's weights (its 1D layer widened,
# docs/training.md "Warm starts"): its first four epochs were ahead of the 32x64 run from random
# weights at every epoch (training-runs/cross3d-32x64-moving-long/card.md). Stopped after epoch 4
# of 80: the epochs left need about 11 h of both cores, resumed three times, and more run-state
# commits (31 MB each) than its budget allows; its card says how to resume it by hand. Not in the queue.
# seldnet-lr1e-3: SELDnet again on the paper's spectrogram recipe (T60 0-0.3 s) at its own learning
# rate, 1e-3 then 1e-4, for 32 epochs (its 18-epoch run at 1e-4 was still falling; this one planned 24 and
# was still falling 0.2 deg an epoch at its 20th, so it went on). spec-cnn2d-ipd: spec-cnn2d on the same
# recipe reading the phases relative to the first microphone's (--tracker-opt phase=relative): on each
# microphone's own phase (the paper's text) it fitted neither 20 anechoic trajectories at any rate
# tried nor, in 2 epochs from its He initialisation (training-runs/spec-cnn2d-he, stopped there), the
# held validation set; relative phases fit them (docs/training.md, "The spectrogram models: what was
# measured"). It was stopped after epoch 15 of 18: its held validation had stopped falling at the
# second phase's rate (epochs 10-15: 18.68, 18.37, 18.40, 18.12, 18.18, 18.17 deg), and its best
# epoch, 13, was exported (training-runs/spec-cnn2d-ipd/card.md). Each exports beside the shipped run;
# the default rule (docs/models.md) decides whether it becomes its tracker's default (spec-cnn2d-ipd
# does not: it lags 1.85 s on sim-walk).
QUEUE=(
    "cross3d:16x32 paper cross3d-16x32 cross3d-16x32 float32 0 1"
    "cross3d:8x16 paper cross3d-8x16 cross3d-8x16 float32 0 1"
    "cross3d:4x8 paper cross3d-4x8 cross3d-4x8 float32 0 1"
    "gcc-cnn1d paper gcc-cnn1d gcc-cnn1d float16 2.6 1"
    "max-cnn1d:64x128 paper max-cnn1d-64x128 max-cnn1d-64x128 float16 2.4 1"
    "seldnet paper seldnet seldnet float32 0 1 --epochs 18 --switch-epoch 9"
    "spec-cnn2d paper spec-cnn2d spec-cnn2d float32 0 2 --epochs 18 --switch-epoch 9"
    "cross3d:16x32 paper cross3d-16x32-v3 cross3d-16x32-v3 float32 0 1/2"
    "cross3d:16x32 paper cross3d-16x32-moving cross3d-16x32-moving float32 0 1/2 --task sim-train-moving"
    "cross3d:8x16 paper cross3d-8x16-moving cross3d-8x16-moving float32 0 1/2 --task sim-train-moving"
    "cross3d:32x64 paper cross3d-32x64-moving cross3d-32x64-moving float32 0 2 --task sim-train-moving --epochs 18 --switch-epoch 10"
    "cross3d:16x32 paper cross3d-16x32-moving-long cross3d-16x32-moving-long float32 0 1/2 --task sim-train-moving --tracker-opt weights=moving"
    "seldnet paper seldnet-lr1e-3 seldnet-lr1e-3 float32 0 1 --epochs 32 --switch-epoch 12 --lr 1e-3,1e-4"
    "spec-cnn2d paper spec-cnn2d-ipd spec-cnn2d-ipd float32 0 2 --epochs 18 --switch-epoch 9 --tracker-opt phase=relative"
)

native_bf16=""  # asked once, only when an entry's threads depend on it (QUEUE_NATIVE_BF16=0/1 overrides)
resolve_threads() {  # an entry's threads field ("N", or "B/F": see above) -> $threads
    [[ "$threads" == */* ]] || return 0
    if [ -z "$native_bf16" ]; then
        native_bf16="${QUEUE_NATIVE_BF16:-$("$PYTHON" -c 'from doabench.training.trainer import cpu_has_native_bf16; print(int(cpu_has_native_bf16()))')}"
    fi
    if [ "$native_bf16" = 1 ]; then threads="${threads%/*}"; else threads="${threads#*/}"; fi
}

deferred=()
for entry in "${QUEUE[@]}"; do
    read -r model preset name weights_name dtype whole_hours threads extra_text <<< "$entry"
    read -r -a extra <<< "${extra_text:-}"
    out="training-runs/$name"
    weights="baselines/weights/$weights_name.safetensors"
    if [ -f "$out/exported.txt" ]; then
        continue
    fi
    resolve_threads
    resume=()
    if [ -f "$out/checkpoint.safetensors" ]; then
        resume=(--resume)
        # the run keeps the recipe it started with: its task is named again (train checks it), and
        # the entry's schedule (--epochs, --switch-epoch) is passed on, which a resumed run may take
        # while the switch is still ahead (so an entry's schedule can be shortened mid-run)
        kept=()
        for ((i = 0; i < ${#extra[@]}; i++)); do
            case "${extra[i]}" in
                --task | --epochs | --switch-epoch | --tracker-opt) kept+=("${extra[i]}" "${extra[i + 1]}") ;;
            esac
        done
        extra=(${kept[@]+"${kept[@]}"})
    elif [ -n "$DEADLINE" ] && [ "$whole_hours" != 0 ]; then
        need=$(awk -v h="$whole_hours" 'BEGIN { printf "%d", h * 3600 }')
        if [ $(( $(date +%s) + need )) -gt "$DEADLINE" ]; then
            echo "== $(date -u +%FT%TZ) $model deferred: it needs ${whole_hours} h without a stop, $(( (DEADLINE - $(date +%s)) / 60 )) min left"
            deferred+=("$model")
            continue
        fi
    fi
    opts=()
    # the paper preset trains from random weights unless the entry names the weights to start from
    [ "$preset" = paper ] && [[ " ${extra[*]+${extra[*]}} " != *" weights="* ]] && opts=(--tracker-opt weights=random)
    echo "== $(date -u +%FT%TZ) $model ($preset) -> $out ${resume[*]}"
    # returns once every epoch of the recipe is done (immediately for a finished run)
    "$DOABENCH" train --tracker "$model" "${opts[@]}" --preset "$preset" --librispeech "$LIBRI" \
        --out "$out" --quiet --threads "$threads" ${extra[@]+"${extra[@]}"} ${resume[@]+"${resume[@]}"}
    "$DOABENCH" train --tracker "$model" --tracker-opt weights=random --out "$out" --export-dtype "$dtype" --export "$weights"
    sha=$(sha256sum "$weights" | cut -d' ' -f1)
    # the shipped files' manifest (baselines/weights/SHA256SUMS, sha256sum format, sorted by name)
    manifest=baselines/weights/SHA256SUMS
    { grep -v "  $weights_name.safetensors\$" "$manifest" || true; echo "$sha  $weights_name.safetensors"; } \
        | sort -k2 > "$manifest.tmp" && mv "$manifest.tmp" "$manifest"
    rm -f "$out/checkpoint.safetensors"
    printf 'exported %s (%s preset) to %s (sha256 %s) on %s\n' "$model" "$preset" "$weights" "$sha" \
        "$(date -u +%FT%TZ)" > "$out/exported.txt"
done
if [ ${#deferred[@]} -gt 0 ]; then
    echo "== deferred to a later run of the queue with time for them: ${deferred[*]}"
    exit 0
fi
echo "== the queue is done: run scripts/evaluate_paper.sh (docs/results.md)"
