#!/usr/bin/env bash
# Renders the demo's request under every device-limit profile and compares the outputs.
#
# The demo's request (scripts/demo/demo.sh: the shipped model, scene_1000002, inputs 0,4,7, a 24-view
# path, ten labels) without a device-limit profile and under each one (SPAR_DEVICE_LIMITS), and
# every profile's render compared with the unconstrained one (scripts/compare/compare_renders.py: the
# lowest PSNR over the views, masks and label maps identical or not, cameras). One line each.
#
#   bash scripts/portability/profiles-demo.sh [OUT_DIR]     (default out/profiles; after scripts/setup/build.sh)
set -euo pipefail
cd "$(dirname "$0")/../.."
out=${1:-out/profiles}
scene=data/scenes/scene_1000002
labels="wall,floor,ceiling,sofa,table,window,door,plant,person,pet"
spar=${SPAR_BUILD:-build}/bin/spar
rm -rf "$out"
mkdir -p "$out"
render() {  # NAME [profile [kernel family]]
  local start end
  start=$(date +%s.%N)
  SPAR_DEVICE_LIMITS=${2:-} SPAR_KERNELS=${3:-} "$spar" render --model data/spar_rooms.spar --frames "$scene"/rgb_0{0..7}.png \
    --inputs 0,4,7 --path 24 --labels "$labels" --out "$out/$1" > "$out/$1.log" 2>&1
  end=$(date +%s.%N)
  printf '%.1f' "$(echo "$end - $start" | bc)"
}
echo "none: $(render none) s"
status=0
for p in vulkan-1.2-min android-baseline-2022 raspberry-pi-5 mali-g610 adreno-610; do
  t=$(render "$p" "$p") || { echo "$p: render failed: $(tail -1 "$out/$p.log")"; status=1; continue; }
  line=$(/usr/bin/python3 scripts/compare/compare_renders.py "$out/none" "$out/$p") || status=1
  echo "$p: $t s; $line"
done
# The GPU kernel family (what a phone's or a board's GPU gets) under the GPU profiles, against
# the same unconstrained CPU-family render: equal within fp32 rounding, masks identical.
for p in raspberry-pi-5 mali-g610 adreno-610; do
  t=$(render "$p-gpu" "$p" gpu) || { echo "$p, GPU kernels: render failed: $(tail -1 "$out/$p-gpu.log")"; status=1; continue; }
  line=$(/usr/bin/python3 scripts/compare/compare_renders.py "$out/none" "$out/$p-gpu") || status=1
  echo "$p, GPU kernels: $t s; $line"
done
exit $status
