#!/usr/bin/env bash
# Maintainers: set up .venv and resume the training queue in the background for as long as the
# machine is free. The queue runs at nice 10 with a deadline 15 minutes before the machine is needed
# back, so that a run whose state is too large to commit mid-run is only started when it can finish
# (scripts/train_queue.sh). Its log goes to runs/queue.log. Before the machine is needed back, stop
# the training and commit its state with scripts/commit_run_state.sh; the next call resumes it.
#
#   scripts/train_in_background.sh                    # the machine is free for 180 minutes
#   TRAIN_MINUTES=120 scripts/train_in_background.sh
set -euo pipefail
cd "$(dirname "$0")/.."
minutes="${TRAIN_MINUTES:-180}"
if ! [[ "$minutes" =~ ^[0-9]+$ ]] || [ "$minutes" -le 15 ]; then
    echo "TRAIN_MINUTES must be a whole number of minutes above 15, got '$minutes'" >&2
    exit 2
fi
if pgrep -f "scripts/train_queue.sh" >/dev/null; then
    echo "the training queue is already running (see runs/queue.log)" >&2
    exit 2
fi
make --no-print-directory setup
mkdir -p runs
deadline=$(( $(date +%s) + (minutes - 15) * 60 ))
QUEUE_DEADLINE=$deadline nohup nice -n 10 scripts/train_queue.sh >> runs/queue.log 2>&1 &
echo "training queue started (pid $!, deadline $(date -u -d "@$deadline" +%H:%MZ)); log: runs/queue.log"
