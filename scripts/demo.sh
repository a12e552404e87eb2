#!/usr/bin/env bash
# The main job of run.sh: render novel views with `spar render` from the sample photos in
# samples/data/room/ (four frames of a room where a person walks by).
#
# No trained SPAR weights ship yet (a small model trained on synthetic rooms is the next issue):
# until then the demo model is the tiny test configuration with random weights, made here by the
# PyTorch reference and packed by the converter. The renders show the pipeline running end to end
# (cameras, motion maps, novel views along a camera path), not meaningful pictures.
#
#   bash scripts/demo.sh [extra spar render options, e.g. --device 0 or --assume-static]
set -euo pipefail
cd "$(dirname "$0")/.."
model_dir=build/demo
model=$model_dir/demo.spar
if [[ ! -f $model ]]; then
  mkdir -p "$model_dir"
  echo "demo: making the demo model (tiny configuration, random weights) in $model_dir"
  /usr/bin/python3 converter/spar-reference make-checkpoint --config samples/data/demo_config.json \
    --seed 1 --perturb --no-optimizer -o "$model_dir/demo.pt"
  /usr/bin/python3 converter/spar-convert -q "$model_dir/demo.pt" --config samples/data/demo_config.json -o "$model"
  rm -f "$model_dir/demo.pt"
fi
out=out/demo
rm -rf "$out"
mkdir -p out
./build/samples/spar render --model "$model" --images samples/data/room/frame_{0,1,2,3}.png --path 8 --out "$out" "$@"
echo "demo: views along a camera path through the input cameras: $out/view_*.png;"
echo "      motion probability and masks of the inputs: $out/motion_*.png, $out/mask_*.png;"
echo "      cameras: $out/cameras.json; stage times: $out/report.json"
