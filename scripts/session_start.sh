#!/usr/bin/env bash
# Maintainers: at the start of a working session, set up .venv and resume the training queue.
# The queue runs in the background (nice 10), with the session's deadline so that a run whose state is too
# large to commit mid-run is only started when it can finish (scripts/train_queue.sh). Its log
# goes to runs/queue.log. End the session with scripts/commit_run_state.sh.
#
#   scripts/session_start.sh              # a 180-minute session: training until 15 min before its end
#   SESSION_MINUTES=120 scripts/session_start.sh
set -euo pipefail
cd "$(dirname "$0")/.."
minutes="${SESSION_MINUTES:-180}"
if ! [[ "$minutes" =~ ^[0-9]+$ ]] || [ "$minutes" -le 15 ]; then
    echo "SESSION_MINUTES must be a whole number of minutes above 15, got '$minutes'" >&2
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
