#!/usr/bin/env bash
# End of a working session: commit the state of every unfinished training run (issue 12, "runs
# that outlast a working day"). Waits for the running `doabench train` to finish its current
# epoch (--now: do not wait; the epoch in progress is then redone on resume), stops it, compacts
# each unfinished run's checkpoint (Adam moments and best weights in bfloat16, about 40 % smaller:
# `doabench train --compact`) and commits training-runs/ (and baselines/weights/ when the queue
# exported something). The next session resumes with scripts/train_queue.sh.
#
#   scripts/commit_run_state.sh          # wait for the epoch boundary (at most --max-wait seconds, default 900)
#   scripts/commit_run_state.sh --now
set -euo pipefail
cd "$(dirname "$0")/.."
DOABENCH="${DOABENCH:-.venv/bin/doabench}"
WAIT=1
MAX_WAIT=900
while [ $# -gt 0 ]; do
    case "$1" in
        --now) WAIT=0 ;;
        --max-wait) MAX_WAIT="$2"; shift ;;
        *) echo "usage: $0 [--now] [--max-wait SECONDS]" >&2; exit 2 ;;
    esac
    shift
done

running=$(pgrep -f "doabench train" || true)
if [ -n "$running" ] && [ "$WAIT" = 1 ]; then
    # the run that is going: the newest checkpoint under training-runs/
    log=$(ls -t training-runs/*/log.csv 2>/dev/null | head -1)
    n=$(wc -l < "$log")
    echo "waiting for the epoch in progress of $(dirname "$log") to finish (at most $MAX_WAIT s)"
    waited=0
    while [ "$(wc -l < "$log")" -le "$n" ] && [ "$waited" -lt "$MAX_WAIT" ]; do sleep 5; waited=$((waited + 5)); done
fi
if [ -n "$running" ]; then
    pkill -f "scripts/train_queue.sh" || true
    pkill -INT -f "doabench train" || true
    for _ in $(seq 30); do pgrep -f "doabench train" >/dev/null || break; sleep 1; done
    pkill -KILL -f "doabench train" || true
fi
for ck in training-runs/*/checkpoint.safetensors; do
    [ -f "$ck" ] || continue
    run=$(dirname "$ck")
    tracker=$(python3 -c "import json,sys; print(json.load(open('$run/config.json'))['tracker'])" 2>/dev/null || echo "${run##*/}")
    "$DOABENCH" train --tracker "$tracker" --out "$run" --compact
    echo "$run: after epoch $(tail -1 "$run/log.csv" | cut -d, -f1)"
done
git add training-runs
[ -d baselines/weights ] && git add baselines/weights
summary=$(for r in training-runs/*/log.csv; do printf '%s epoch %s\n' "$(basename "$(dirname "$r")")" "$(tail -1 "$r" | cut -d, -f1)"; done | paste -sd, - | sed 's/,/, /g')
git commit -m "training-runs: run state at the end of a session ($summary)" || echo "nothing to commit"
