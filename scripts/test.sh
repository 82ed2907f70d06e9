#!/usr/bin/env bash
# Set up (if needed) and run every check: lint, format, types of the pure modules, tests.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ ! -x .venv/bin/pytest ] || [ ! -x .venv/bin/ruff ]; then
  bash scripts/setup.sh dev
fi
.venv/bin/ruff check .
.venv/bin/ruff format --check .
.venv/bin/itnet --version
# Four groups. 1: every test that does not time itself, on both cores (pytest-xdist). 2: the
# hardening tests that do not time themselves, on both cores, each file in one worker: they resize
# process-wide thread pools and handle signals, so they run apart from the other tests. 3: the
# tests that assert wall-clock time (a budget held, a reply within N ms), alone on the machine.
# 4: the Ray tests, last and on their own: they leave Ray's threads and its SIGTERM handler behind
# in the process, and other tests fork (training's batch workers). A test that hangs fails after
# pyproject's pytest timeout, with every thread's stack printed.
.venv/bin/python -m pytest -q -n 2 --ignore=tests/hardening -m "not ray and not timing" "$@"
# The types of the pure modules are checked beside the second group (none of it times itself);
# mypy's verdict is read after that group.
types=$(mktemp)
.venv/bin/mypy itnet/geometry.py itnet/preprocess.py itnet/metrics.py itnet/cloud_io.py itnet/alignment/overlap.py \
  itnet/alignment/hypotheses.py itnet/symmetry.py itnet/fusion.py itnet/cpu.py itnet/size_prior.py itnet/atomic_write.py \
  itnet/pose/request.py itnet/pose/plan.py itnet/pose/stages.py itnet/pose/loop.py itnet/pose/step_batcher.py \
  itnet/pose/admission.py itnet/pose/shared_work.py itnet/pose/catalog.py itnet/request_fields.py itnet/commands/request_options.py \
  itnet/measurements.py itnet/graph_digest.py itnet/scene itnet/recordings >"$types" 2>&1 &
mypy_pid=$!
.venv/bin/python -m pytest -q -n 2 --dist loadfile tests/hardening -m "not timing" "$@"
if ! wait "$mypy_pid"; then cat "$types" >&2; exit 1; fi
cat "$types"
# Group 3 collects only the files that mark a test timing (collecting every file takes seconds).
mapfile -t timed < <(git grep -l -e "mark.timing" -- tests 2>/dev/null || grep -rl -e "mark.timing" tests)
.venv/bin/python -m pytest -q -m "timing and not ray" "${timed[@]}" "$@"
.venv/bin/python -m pytest -q -m ray tests/scale "$@"
# The tree describes the product as it is: no words about work sessions, borrowed machines or issue numbers
# (in code, tests, docs, help texts). Every tracked file is checked, nothing is excluded. Run
# last, so that a hit does not hide the tests' results.
if git rev-parse --is-inside-work-tree >/dev/null 2>&1 \
  && hits=$(git grep -nIiE '\bsession [0-9]+|\blease|\bissue [0-9]+'); then
  echo "error: words about work sessions, borrowed machines or issue numbers in tracked files; say what the" >&2
  echo "product does instead (the history belongs in commit messages):" >&2
  echo "$hits" >&2
  exit 1
fi
