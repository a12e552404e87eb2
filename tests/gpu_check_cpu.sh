#!/bin/sh
# CTest gpu_check_cpu: scripts/gpu-check.sh as far as this CPU allows: `pack` (the bundle the
# GPU machine gets) and `run --cpu-coopmat` (every step with small shapes on lavapipe 26.1, DIR
# of scripts/coopmat-lavapipe.sh, with the plan a GPU takes: cooperative matrices for fp16
# weights, tiles measured), then the report must say every step ran (exit 0), every test
# program passed (test_coopmat among them), the plan used cooperative matrices, and hold the
# engine's and the PyTorch reference's model timings. Arguments: BUILD_DIR SOURCE_DIR SCRATCH_DIR.
set -eu
build=$1 src=$2 scratch=$3
rm -rf "$scratch" && mkdir -p "$scratch"
cd "$src"
SPAR_BUILD="$build" bash scripts/gpu-check.sh pack
OUT="$scratch/out" GPU_CHECK_WORK="$scratch/work" bash scripts/gpu-check.sh run --cpu-coopmat > "$scratch/run.log" 2>&1 ||
  { tail -n 30 "$scratch/run.log"; exit 1; }
/usr/bin/python3 - "$scratch/out/report.json" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
bad = {k: v for k, v in r["steps"].items() if v != 0}
assert not bad, f"steps that failed: {bad}"
assert len(r["tests"]) >= 20 and all(t["failures"] == 0 for t in r["tests"]), r["tests"]
assert any(t["program"] == "test_coopmat" and t["tests"] > 0 for t in r["tests"]), r["tests"]
assert any("gemm_coopmat.comp" in line for line in r["kernels"]), r["kernels"]
assert r["model"]["engine_fp32"]["total"]["gpu_ms"] > 0 and r["model"]["engine_fp16"]["total"]["gpu_ms"] > 0
assert r["model"]["reference"]["modes"]["fp32"]["total_ms"] > 0
assert any(o["op"] == "gemm_f32" and o["torch_ms"] for o in r["ops"]), r["ops"]
print(f"gpu-check --cpu: {len(r['steps'])} steps, {sum(t['tests'] for t in r['tests'])} tests, report ok")
PY
