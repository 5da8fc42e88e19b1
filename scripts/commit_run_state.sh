#!/usr/bin/env bash
# Maintainers: before the machine is needed back, commit the state of every unfinished training run.
# Long runs outlast the time a machine is free, so their state is committed and resumed later. Waits for the running `doabench train` to finish its current
# epoch (--now: do not wait; the epoch in progress is then redone on resume), stops it, compacts
# each unfinished run's checkpoint (Adam moments and best weights in bfloat16, about 40 % smaller:
# `doabench train --compact`) and commits training-runs/ (and baselines/weights/ when the queue
# exported something). scripts/train_queue.sh (or scripts/train_in_background.sh) resumes them.
#
#   scripts/commit_run_state.sh          # wait for the epoch boundary (at most --max-wait seconds, default 900)
#   scripts/commit_run_state.sh --now
#
# Budget: run states may add at most RUN_STATE_BUDGET_MB (default 391: 150 for the paper-recipe
# queue, which used 140 of them, 100 more for the moving-talker runs, 21 for the shortened 32x64
# run, and 120 for the 32x64 run on the paper's full schedule) to the repository in all (every committed checkpoint stays in the history). A run whose compacted
# checkpoint would take the total over it is left out of the commit entirely (a later run
# continues it from its last committed state, or from scratch) unless --force is given. Only
# training processes of this checkout (working directory here) are stopped.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd -P)
DOABENCH="${DOABENCH:-.venv/bin/doabench}"
BUDGET_MB="${RUN_STATE_BUDGET_MB:-391}"
WAIT=1
MAX_WAIT=900
FORCE=0
while [ $# -gt 0 ]; do
    case "$1" in
        --now) WAIT=0 ;;
        --force) FORCE=1 ;;
        --max-wait) MAX_WAIT="$2"; shift ;;
        *) echo "usage: $0 [--now] [--force] [--max-wait SECONDS]" >&2; exit 2 ;;
    esac
    shift
done

ours() {  # PIDs whose command line matches $1 and whose working directory is this checkout
    local pid
    for pid in $(pgrep -f "$1" || true); do
        [ "$(readlink "/proc/$pid/cwd" 2>/dev/null)" = "$ROOT" ] && echo "$pid"
    done
    return 0
}

running=$(ours "doabench train")
if [ -n "$running" ] && [ "$WAIT" = 1 ]; then
    # the run that is going: the --out of the training process (a run in its first epoch has no
    # log.csv yet, so the newest log under training-runs/ would name a finished run)
    pid=$(echo "$running" | head -1)
    out=$(tr '\0' ' ' < "/proc/$pid/cmdline" 2>/dev/null | sed -n 's/.*--out[= ]\([^ ]*\).*/\1/p')
    [ -n "$out" ] || out=$(dirname "$(ls -t training-runs/*/log.csv 2>/dev/null | head -1)")
    log="$out/log.csv"
    lines() { if [ -f "$log" ]; then wc -l < "$log"; else echo 0; fi; }
    n=$(lines)
    echo "waiting for the epoch in progress of $out to finish (at most $MAX_WAIT s)"
    waited=0
    while [ "$(lines)" -le "$n" ] && [ "$waited" -lt "$MAX_WAIT" ]; do sleep 5; waited=$((waited + 5)); done
fi
if [ -n "$running" ]; then
    queue=$(ours "scripts/train_queue.sh")
    [ -z "$queue" ] || kill $queue 2>/dev/null || true
    kill -INT $(ours "doabench train") 2>/dev/null || true
    for _ in $(seq 30); do [ -n "$(ours "doabench train")" ] || break; sleep 1; done
    left=$(ours "doabench train")
    [ -z "$left" ] || kill -KILL $left 2>/dev/null || true
fi
# bytes that committed run states already take in the repository (packed or loose, compressed)
used=$(git rev-list --objects --all -- training-runs \
    | git cat-file --batch-check='%(objecttype) %(objectsize:disk) %(rest)' \
    | awk '$1 == "blob" { s += $2 } END { printf "%d", s }')
left_out=()
for ck in training-runs/*/checkpoint.safetensors; do
    [ -f "$ck" ] || continue
    run=$(dirname "$ck")
    tracker=$(python3 -c "import json,sys; print(json.load(open('$run/config.json'))['tracker'])" 2>/dev/null || echo "${run##*/}")
    "$DOABENCH" train --tracker "$tracker" --out "$run" --compact
    size=$(stat -c %s "$ck")
    if [ $(( used + size )) -gt $(( BUDGET_MB * 1000000 )) ] && [ "$FORCE" = 0 ]; then
        echo "$run: not committed: its $(( size / 1000000 )) MB state would take the run states to" \
             "$(( (used + size) / 1000000 )) MB, over the ${BUDGET_MB} MB budget (--force commits it anyway)" >&2
        left_out+=("$run")
        continue
    fi
    used=$(( used + size ))
    echo "$run: after epoch $(tail -1 "$run/log.csv" | cut -d, -f1)"
done
git add training-runs
for run in ${left_out[@]+"${left_out[@]}"}; do git reset -q -- "$run"; done
[ -d baselines/weights ] && git add baselines/weights
summary=$(for r in training-runs/*/log.csv; do printf '%s epoch %s\n' "$(basename "$(dirname "$r")")" "$(tail -1 "$r" | cut -d, -f1)"; done | paste -sd, - | sed 's/,/, /g')
git commit -m "training-runs: run state at a stop ($summary)" || echo "nothing to commit"
