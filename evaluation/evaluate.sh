#!/usr/bin/env bash
# Makes the evaluation table of docs/evaluation.md on held-out test scenes.
#
# The evaluation table of docs/evaluation.md: the paper's metrics (evaluation/PROTOCOL.md) on held-out
# test scenes, for the trained model, its inference modes and the model trained without the
# dynamic-region-aware loss, on the engine (`spar eval`) and on the PyTorch reference
# (`spar-eval-reference`), which must agree to the second decimal (`spar-eval-compare`).
#
#   bash evaluation/evaluate.sh [MAIN_RUN] [NO_DYN_RUN] [SCENES] [CONTROL_RUN]
#
# MAIN_RUN / NO_DYN_RUN: spar-train run directories (checkpoint.pt, config.json, model.spar);
# default build/train/main and build/train/no-dyn (rows left out when it is missing). SCENES:
# number of test scenes (default 12). CONTROL_RUN: when MAIN_RUN was trained longer than the
# ablation, a run with the dynamic-region-aware loss and exactly the ablation's seed, steps and
# teacher, so the ablation is compared at an equal budget (rows left out when not given).
# Writes $EVAL_OUT/*.json (default build/eval; an existing result is kept: delete it to run
# again) and $EVAL_OUT/table.md. Runs one thing at a time (2 cores).
set -euo pipefail
cd "$(dirname "$0")/.."
main=${1:-build/train/main}
nodyn=${2:-build/train/no-dyn}
count=${3:-12}
control=${4:-}
out=${EVAL_OUT:-build/eval}
scenes=build/eval/test-scenes-$count
spar=${SPAR_BUILD:-build}/bin/spar
py=/usr/bin/python3
mkdir -p "$out" build/eval
steps() { grep -o -m1 '[0-9]* steps of' "$1/train_log.txt" | cut -d' ' -f1; }
[[ -d $scenes ]] || $py scenes/spar-scenes split --split test --count "$count" --out "$scenes"

engine() {  # name model [spar eval options]
  local name=$1 model=$2
  shift 2
  [[ -f $out/engine-$name.json ]] && return 0
  $spar eval --model "$model" --scenes "$scenes" --out "$out/engine-$name.json" "$@"
}
reference() {  # name run [spar-eval-reference options]
  local name=$1 run=$2
  shift 2
  [[ -f $out/reference-$name.json ]] && return 0
  $py evaluation/spar-eval-reference --checkpoint "$run/checkpoint.pt" --config "$run/config.json" \
    --scenes "$scenes" --quiet --out "$out/reference-$name.json" "$@"
}

engine trained "$main/model.spar"
engine trained-fp16 "$main/model.spar" --precision fp16
engine no-gating "$main/model.spar" --no-gating
engine assume-static "$main/model.spar" --assume-static
reference trained "$main"
reference no-gating "$main" --no-gating
reference assume-static "$main" --assume-static
names="trained no-gating assume-static"
rows=()
if [[ -n $control ]]; then
  engine control "$control/model.spar"
  reference control "$control"
  names="$names control"
  rows+=(--row "with the loss, $(steps "$control") steps (control)=$out/engine-control.json"
         --row "reference: control=$out/reference-control.json")
fi
if [[ -f $nodyn/model.spar ]]; then
  engine no-dyn-loss "$nodyn/model.spar"
  reference no-dyn-loss "$nodyn"
  names="$names no-dyn-loss"
  rows+=(--row "without the dynamic-region-aware loss, $(steps "$nodyn") steps=$out/engine-no-dyn-loss.json"
         --row "reference: without the dynamic-region-aware loss=$out/reference-no-dyn-loss.json")
fi

status=0
for name in $names; do
  $py evaluation/spar-eval-compare "$out/engine-$name.json" "$out/reference-$name.json" --tolerance 0.005 \
    > "$out/compare-$name.txt" || status=1
  tail -1 "$out/compare-$name.txt" | sed "s/^/$name: /"
done
$py evaluation/spar-eval-table --out "$out/table.md" \
  --row "SPAR small, $(steps "$main") steps, fp32=$out/engine-trained.json" \
  --row "SPAR small, fp16 weights=$out/engine-trained-fp16.json" \
  --row "no gating (every token kept)=$out/engine-no-gating.json" \
  --row "--assume-static (no DINOv3, no CV-DRP)=$out/engine-assume-static.json" \
  --row "reference: SPAR small=$out/reference-trained.json" \
  --row "reference: no gating=$out/reference-no-gating.json" \
  --row "reference: --assume-static=$out/reference-assume-static.json" "${rows[@]}"
cat "$out/table.md"
exit $status
