#!/usr/bin/env bash
# Set up (if needed) and run every check: lint, format, types of the pure modules, tests.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ ! -x .venv/bin/pytest ] || [ ! -x .venv/bin/ruff ]; then
  bash scripts/setup.sh dev
fi
.venv/bin/ruff check .
.venv/bin/ruff format --check .
.venv/bin/mypy itnet/geometry.py itnet/preprocess.py itnet/metrics.py itnet/cloud_io.py itnet/alignment/overlap.py \
  itnet/alignment/hypotheses.py itnet/symmetry.py itnet/fusion.py itnet/cpu.py itnet/size_prior.py itnet/atomic_write.py \
  itnet/pose/request.py itnet/pose/plan.py itnet/pose/stages.py itnet/pose/loop.py itnet/pose/step_batcher.py \
  itnet/pose/admission.py itnet/pose/catalog.py itnet/request_fields.py itnet/commands/request_options.py \
  itnet/scene itnet/recordings
.venv/bin/itnet --version
# Three processes. tests/hardening resizes process-wide thread pools and handles signals (one
# of its timing tests fails when tests/align ran first in the same process). The Ray tests
# leave Ray's threads and its SIGTERM handler behind in the process, and the suite forks after
# them (training's batch workers, torch.compile's compiler): they run last, on their own.
# A test that hangs fails after pyproject's pytest timeout, with every thread's stack printed.
.venv/bin/python -m pytest -q --ignore=tests/hardening -m "not ray" "$@"
.venv/bin/python -m pytest -q tests/hardening "$@"
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
