#!/usr/bin/env bash
# Set up itnet on a fresh Debian/Ubuntu machine: system libraries for open3d, then a virtual
# environment in .venv with the package and the extras given (default: refine).
#   scripts/setup.sh            # serving + CLI + ICP refinement
#   scripts/setup.sh dev        # everything: training, export, tests, lint
# Quiet: apt and pip print errors only (pip's -qq hides its warnings, e.g. about index
# locations of this machine's pip configuration that do not exist); a failure still stops the
# script with pip's own message.
set -euo pipefail
cd "$(dirname "$0")/.."
extras="${1:-refine}"
if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
  # open3d needs libusb-1.0 and libgomp even on a headless machine.
  if ! ldconfig -p | grep -q libusb-1.0.so.0 || ! ldconfig -p | grep -q libgomp.so.1; then
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0 libgomp1 >/dev/null
  fi
elif ! ldconfig -p 2>/dev/null | grep -q libusb-1.0.so.0; then
  echo "note: open3d needs libusb-1.0 (e.g. sudo apt-get install libusb-1.0-0 libgomp1)" >&2
fi
python3 -m venv .venv
export PIP_DISABLE_PIP_VERSION_CHECK=1
.venv/bin/python -m pip install -qq --upgrade pip
# torch is pinned (==2.13.0) in the extras that need it: a CPU build, no CUDA download here.
.venv/bin/python -m pip install -qq -e ".[${extras}]"
echo "itnet installed in .venv with extras [${extras}]: $(.venv/bin/itnet --version)"
