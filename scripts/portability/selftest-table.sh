#!/usr/bin/env bash
# Runs `spar selftest` on every CPU Vulkan driver here under every device-limit profile: one table.
#
# `spar selftest` on each lavapipe this machine can run (the system's Mesa 22.3, 25.0 from
# bookworm-backports: scripts/portability/newer-lavapipe.sh, 26.1 from trixie-backports with cooperative
# matrices: scripts/portability/coopmat-lavapipe.sh) and on SwiftShader (chromium's, `--device
# swiftshader`), under each device-limit profile: one markdown table row each (verdict, checks
# passed: the op checks and the self-test model's stages, validation messages, wall time).
#
#   bash scripts/portability/selftest-table.sh [SPAR]     (default build/bin/spar; network for the drivers)
#   DRIVERS="swiftshader" bash scripts/portability/selftest-table.sh   (some of: system newer coopmat swiftshader)
set -euo pipefail
cd "$(dirname "$0")/../.."
spar=$(realpath "${1:-build/bin/spar}")
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
echo "| driver | profile | verdict | checks | validation messages | wall |"
echo "|---|---|---|---|---|---|"
for driver in ${DRIVERS:-system newer coopmat swiftshader}; do
  for profile in "" vulkan-1.2-min android-baseline-2022 raspberry-pi-5 mali-g610 adreno-610; do
    device=()
    case $driver in
      system) run=();;
      newer) run=(bash scripts/portability/newer-lavapipe.sh run);;
      coopmat) run=(env DIR="${COOPMAT_DIR:-build/tests/mesa-trixie}" bash scripts/portability/coopmat-lavapipe.sh run);;
      swiftshader) run=(); device=(--device swiftshader);;
      *) echo "selftest-table.sh: unknown driver '$driver' (system, newer, coopmat, swiftshader)" >&2; exit 2;;
    esac
    start=$(date +%s.%N)
    code=0
    SPAR_DEVICE_LIMITS=$profile "${run[@]}" "$spar" selftest "${device[@]}" --json > "$tmp/out.json" 2> "$tmp/err.txt" || code=$?
    wall=$(echo "$(date +%s.%N) - $start" | bc)
    /usr/bin/python3 - "$tmp/out.json" "$code" "${profile:-none}" "$wall" <<'PY'
import json, sys
path, code, profile, wall = sys.argv[1], int(sys.argv[2]), sys.argv[3], float(sys.argv[4])
try:
    d = json.load(open(path))
except Exception:
    print(f"| ? | {profile} | no report (exit {code}) | | | {wall:.1f} s |")
    sys.exit(0)
checks = d["checks"] + d.get("model", {}).get("checks", [])
ok = sum(c["passed"] for c in checks)
print(f"| {d['driver'].split(' (')[0]} | {profile} | {'PASS' if d['passed'] else 'FAIL'} (exit {code}) | "
      f"{ok}/{len(checks)} | {d['validation']['messages']} | {wall:.1f} s |")
PY
  done
done
