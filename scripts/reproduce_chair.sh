#!/usr/bin/env bash
# Reproduce the shipped chair model and every number the README reports about it.
#   bash scripts/reproduce_chair.sh            # trains (about 60-90 min on 2 idle cores), then measures
#   SKIP_TRAIN=1 bash scripts/reproduce_chair.sh   # measure an existing runs/chair/best.pt
set -euo pipefail
cd "$(dirname "$0")/.."
[ -x .venv/bin/itnet ] || bash scripts/setup.sh dev
export MALLOC_MMAP_THRESHOLD_=33554432  # steadier, faster torch on CPU
itnet=.venv/bin/itnet
if [ -z "${SKIP_TRAIN:-}" ]; then
  $itnet train --out runs/chair
fi
# The anytime curve on the test split (5 random views per held-out chair), torch path.
$itnet eval --checkpoint runs/chair/best.pt --out runs/eval_torch --dump-scans runs/test_scans
# Ship it: ONNX with the measured accuracy in its model card.
$itnet export runs/chair/best.pt --report runs/eval_torch/report.json --out itnet/models/chair.onnx
.venv/bin/python -c "from pathlib import Path; from itnet.model.train import ship_checkpoint as s; s(Path('runs/chair/best.pt'), Path('itnet/models/chair.pt'))"
# The same curve through onnxruntime, and through `itnet pose` (the serving engine) file by file.
$itnet eval --onnx itnet/models/chair.onnx --out runs/eval_onnx
cp runs/eval_onnx/anytime.png docs/anytime_chair.png
cp runs/eval_onnx/report.json docs/eval_chair.json
$itnet pose runs/test_scans/*.npy --json --max-iterations 10 > runs/pose_test.jsonl || true
.venv/bin/python benchmarks/score_poses.py runs/test_scans/labels.json runs/pose_test.jsonl
$itnet bench
