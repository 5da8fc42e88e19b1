#!/usr/bin/env bash
# The paper-scale training queue of issue 12, in the issue's order: Cross3D 16x32, 8x16, 4x8,
# gcc-cnn1d, max-cnn1d (64x128 maxima), spec-cnn2d, seldnet, all with `doabench train`'s paper
# preset on sim-train (an entry may name another preset, e.g. finetune, which starts from the
# tracker's shipped weights instead of weights=random). Each run resumes from
# training-runs/<name>/ (the committed run state); a finished run is exported to
# baselines/weights/<weights>.safetensors (SHA256SUMS updated), its checkpoint is deleted
# (log.csv, loss.png and config.json stay as the record) and training-runs/<name>/exported.txt
# says so. Stop it at any time (Ctrl-C, kill) and run it again to continue where it stopped;
# commit training-runs/ (and baselines/weights/) before a session ends.
#
#   nice -n 10 scripts/train_queue.sh                       # LibriSpeech from $DOABENCH_LIBRISPEECH
#   DOABENCH_LIBRISPEECH=/data/LibriSpeech nice -n 10 scripts/train_queue.sh
set -euo pipefail
cd "$(dirname "$0")/.."
LIBRI="${DOABENCH_LIBRISPEECH:-../shared/data/LibriSpeech}"
DOABENCH="${DOABENCH:-.venv/bin/doabench}"
# tracker, preset, run name, weights file name; the paper preset trains from scratch
# (weights=random), finetune starts from the tracker's shipped weights
QUEUE=(
    "cross3d:16x32 paper cross3d-16x32 cross3d-16x32"
    "cross3d:8x16 paper cross3d-8x16 cross3d-8x16"
    "cross3d:4x8 paper cross3d-4x8 cross3d-4x8"
    "gcc-cnn1d paper gcc-cnn1d gcc-cnn1d"
    "max-cnn1d:64x128 paper max-cnn1d-64x128 max-cnn1d-64x128"
    "spec-cnn2d paper spec-cnn2d spec-cnn2d"
    "seldnet paper seldnet seldnet"
)

for entry in "${QUEUE[@]}"; do
    read -r model preset name weights_name <<< "$entry"
    out="training-runs/$name"
    weights="baselines/weights/$weights_name.safetensors"
    if [ -f "$out/exported.txt" ]; then
        continue
    fi
    opts=()
    [ "$preset" = paper ] && opts=(--tracker-opt weights=random)
    resume=()
    if [ -f "$out/checkpoint.safetensors" ]; then
        resume=(--resume)
    fi
    echo "== $(date -u +%FT%TZ) $model ($preset) -> $out ${resume[*]}"
    # returns once every epoch of the recipe is done (immediately for a finished run)
    "$DOABENCH" train --tracker "$model" "${opts[@]}" --preset "$preset" --librispeech "$LIBRI" \
        --out "$out" --quiet "${resume[@]}"
    "$DOABENCH" train --tracker "$model" --tracker-opt weights=random --out "$out" --export "$weights"
    sha=$(sha256sum "$weights" | cut -d' ' -f1)
    rm -f "$out/checkpoint.safetensors"
    printf 'exported %s (%s preset) to %s (sha256 %s) on %s\n' "$model" "$preset" "$weights" "$sha" \
        "$(date -u +%FT%TZ)" > "$out/exported.txt"
done
echo "== the queue is done: run scripts/evaluate_paper.sh (docs/results.md)"
