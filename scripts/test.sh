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
  itnet/alignment/hypotheses.py itnet/symmetry.py itnet/fusion.py itnet/cpu.py itnet/size_prior.py
.venv/bin/itnet --version
# tests/hardening resizes process-wide thread pools and handles signals: it runs in its own
# process (one of its timing tests fails when tests/align ran first in the same process).
.venv/bin/python -m pytest -q --ignore=tests/hardening "$@"
.venv/bin/python -m pytest -q tests/hardening "$@"
