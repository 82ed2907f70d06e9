#!/usr/bin/env bash
# Run a command with this user's training jobs paused, so that a latency measurement has the
# cores to itself; the jobs resume afterwards (also when the command fails or is interrupted).
#   bash scripts/quiet.sh python -m benchmarks.classify_latency --runs 500
# Paused: processes whose command line holds "itnet train", "itnet classify-train" or
# "itnet classify-experiment" (override with QUIET_PATTERN, an extended regex for pgrep -f).
set -uo pipefail
pattern=${QUIET_PATTERN:-itnet (train|classify-train|classify-experiment)}
pids=$(pgrep -u "$(id -u)" -f -- "$pattern" | grep -v -x "$$" || true)
resume() { [[ -n "$pids" ]] && kill -CONT $pids 2>/dev/null; }
trap resume EXIT INT TERM
if [[ -n "$pids" ]]; then
  kill -STOP $pids
  echo "quiet.sh: paused $(echo $pids | wc -w) process(es) matching '$pattern'" >&2
  sleep 1
fi
"$@"
