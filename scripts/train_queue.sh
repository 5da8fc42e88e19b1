#!/usr/bin/env bash
# The paper-scale training queue of issue 12, in the issue's order: Cross3D 16x32, 8x16, 4x8,
# gcc-cnn1d, max-cnn1d (64x128 maxima), spec-cnn2d, seldnet, all with `doabench train`'s paper
# preset on sim-train. Each run resumes from training-runs/<name>/ (the committed run state); a
# finished run is exported to baselines/weights/<name>.safetensors (SHA256SUMS updated), its
# checkpoint is deleted (log.csv, loss.png and config.json stay as the record) and
# training-runs/<name>/exported.txt says so. Stop it at any time (Ctrl-C, kill) and run it again
# to continue where it stopped; commit training-runs/ (and baselines/weights/) before a session
# ends.
#
#   nice -n 10 scripts/train_queue.sh                       # LibriSpeech from $DOABENCH_LIBRISPEECH
#   DOABENCH_LIBRISPEECH=/data/LibriSpeech nice -n 10 scripts/train_queue.sh
set -euo pipefail
cd "$(dirname "$0")/.."
LIBRI="${DOABENCH_LIBRISPEECH:-../shared/data/LibriSpeech}"
DOABENCH="${DOABENCH:-.venv/bin/doabench}"
QUEUE=(cross3d:16x32 cross3d:8x16 cross3d:4x8 gcc-cnn1d max-cnn1d:64x128 spec-cnn2d seldnet)

for model in "${QUEUE[@]}"; do
    name="${model/:/-}"
    out="training-runs/$name"
    weights="baselines/weights/$name.safetensors"
    if [ -f "$out/exported.txt" ]; then
        continue
    fi
    resume=()
    if [ -f "$out/checkpoint.safetensors" ]; then
        resume=(--resume)
    fi
    echo "== $(date -u +%FT%TZ) $model -> $out ${resume[*]}"
    # returns once every epoch of the recipe is done (immediately for a finished run)
    "$DOABENCH" train --tracker "$model" --tracker-opt weights=random --librispeech "$LIBRI" \
        --out "$out" --quiet "${resume[@]}"
    "$DOABENCH" train --tracker "$model" --tracker-opt weights=random --out "$out" --export "$weights"
    sha=$(sha256sum "$weights" | cut -d' ' -f1)
    rm -f "$out/checkpoint.safetensors"
    printf 'exported %s to %s (sha256 %s) on %s\n' "$model" "$weights" "$sha" "$(date -u +%FT%TZ)" > "$out/exported.txt"
done
echo "== the queue is done: run scripts/evaluate_paper.sh (docs/results.md)"
