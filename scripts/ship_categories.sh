#!/usr/bin/env bash
# Evaluate a network trained on several categories and ship one model per category.
#   bash scripts/ship_categories.sh RUN [CATEGORY...]    (default: every ModelNet10 class)
#   KEEP="chair" bash scripts/ship_categories.sh RUN ... # also re-measure shipped models kept as they are
#   bash scripts/ship_categories.sh 'runs/gpu/{category}' bed sofa   # a network per category
#   MODELS=runs/stage ...          # export there instead of itnet/models (check the bar first);
#                                  # the table and plot then go there too (REPORT= overrides)
#   KEEP's reports already in EVALS are not measured again.
# For each category: the test-split curve of the torch checkpoint (occluded views), an int8
# ONNX model with the measured accuracy in its card (itnet/models/<category>.onnx), the same curves
# through onnxruntime (what the service runs) on occluded, surface and paper views; then the table
# and plot of every category in docs/.
set -euo pipefail
cd "$(dirname "$0")/.."
export MALLOC_MMAP_THRESHOLD_=33554432  # steadier, faster torch on CPU
itnet=.venv/bin/itnet
run=${1:?usage: ship_categories.sh RUN [CATEGORY...]}
shift
categories=${*:-bathtub bed chair desk dresser monitor night_stand sofa table toilet}
evals=${EVALS:-runs/eval_categories}
models=${MODELS:-itnet/models}
if [[ "$models" == itnet/models ]]; then report=${REPORT:-docs}; else report=${REPORT:-$models}; fi
mkdir -p "$models"
for cat in $categories; do
  if [[ " ${KEEP:-} " == *" $cat "* ]]; then continue; fi
  checkpoint="${run//\{category\}/$cat}/best.pt"
  $itnet eval --checkpoint "$checkpoint" --category "$cat" --scanner occluded \
    --iterations 20 --out "runs/eval_torch/$cat/occluded" >/dev/null
  $itnet export "$checkpoint" --category "$cat" --int8 \
    --report "runs/eval_torch/$cat/occluded/report.json" --out "$models/$cat.onnx"
done
for cat in $(printf "%s\n" $categories ${KEEP:-} | sort -u); do
  for scanner in occluded surface paper; do
    if [[ " ${KEEP:-} " == *" $cat "* && -f "$evals/$cat/$scanner/report.json" ]]; then continue; fi
    $itnet eval --onnx "$models/$cat.onnx" --scanner "$scanner" --iterations 20 \
      --out "$evals/$cat/$scanner" | tail -n 1
  done
done
.venv/bin/python -m itnet.model.category_report "$evals" "$report"
