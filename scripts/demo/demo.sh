#!/usr/bin/env bash
# The demo: `spar render` of a shipped scene with the shipped model into out/demo (run.sh's main job).
#
# The main job of run.sh: `spar render` with the shipped trained model on a shipped held-out
# scene: 8 frames of a room where a person and a pet move; frames 0, 4 and 7 are the inputs.
# Renders a smooth 24-view camera path through the input cameras with open-vocabulary label
# maps for the scene's class names, motion masks of the inputs, and path.mp4 (views beside their
# label maps; path.gif where ffmpeg is not installed). The model (data/spar_rooms.spar)
# is a small SPAR trained on synthetic rooms by training/spar-train (see training/README.md), not the paper's weights.
#
#   bash scripts/demo/demo.sh [extra spar render options, e.g. --device 0 or --assume-static]
set -euo pipefail
cd "$(dirname "$0")/../.."
scene=data/scenes/scene_1000002
labels="wall,floor,ceiling,sofa,table,window,door,plant,person,pet"
out=out/demo
rm -rf "$out"
mkdir -p out
${SPAR_BUILD:-build}/bin/spar render --model data/spar_rooms.spar --frames "$scene"/rgb_0{0..7}.png \
  --inputs 0,4,7 --path 24 --labels "$labels" --out "$out" "$@"
echo "demo: 24 views along a camera path through the input cameras: $out/view_*.png, as an animation"
echo "      beside their label maps: $(ls "$out"/path.mp4 "$out"/path.gif 2>/dev/null); label maps: $out/labels_*.png / .json;"
echo "      motion probability and masks of the inputs (frames 0, 4, 7): $out/motion_*.png, $out/mask_*.png;"
echo "      cameras: $out/cameras.json; stage times: $out/report.json"
echo "demo: all of it on one page (open it in a browser): $(realpath "$out/index.html")"
