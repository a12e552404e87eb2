#!/bin/sh
# CTest gpu_session_cpu: the one device call for both GPU issues (scripts/gpu/gpu-session.sh) as far
# as this CPU allows. `gpu-check.sh pack` (the bundle the GPU machine gets) and a tiny teacher
# (the real `gpu-session.sh pack` makes the CPU recipe's own, which takes minutes), then
# `gpu-session.sh run --cpu`: the check's every step with small shapes on lavapipe 26.1 (DIR of
# scripts/portability/coopmat-lavapipe.sh) with the plan a GPU takes (cooperative matrices for fp16 weights,
# tiles measured), then the training call at tiny sizes. What comes back must fit the device
# tool (at most 8 files, 16 MiB each, two folders down), `unpack` must give the check's report
# and a packed model; the report must say every step ran (exit 0), every test program passed
# (test_coopmat among them), the plan used cooperative matrices, and hold the engine's and the
# PyTorch reference's model timings. (tests/gpu_train_cpu.sh checks the trained model itself.)
# Arguments: BUILD_DIR SOURCE_DIR SCRATCH_DIR.
set -eu
build=$1 src=$2 scratch=$3
rm -rf "$scratch" && mkdir -p "$scratch"
cd "$src"
SPAR_BUILD="$build" bash scripts/gpu/gpu-check.sh pack
/usr/bin/python3 training/spar-train --out "$scratch/teacher" --cache "$scratch/teacher-cache" --scenes 8 \
  --lseg-steps 5 --steps 1 --save-every 0 --no-pack --threads 1 > "$scratch/teacher.log" 2>&1 ||
  { tail -n 20 "$scratch/teacher.log"; exit 1; }
OUT="$scratch/out" GPU_CHECK_WORK="$scratch/check-work" GPU_TRAIN_WORK="$scratch/train-work" \
  GPU_SESSION_TEACHER="$scratch/teacher/teacher.pt" bash scripts/gpu/gpu-session.sh run --cpu > "$scratch/run.log" 2>&1 ||
  { tail -n 30 "$scratch/run.log"; exit 1; }
files=$(find "$scratch/out" -type f | wc -l)
[ "$files" -le 8 ] || { echo "gpu_session_cpu: $files files to bring back (the device tool brings 8)"; exit 1; }
big=$(find "$scratch/out" -type f -size +16M)
[ -z "$big" ] || { echo "gpu_session_cpu: over 16 MiB: $big"; exit 1; }
deep=$(find "$scratch/out" -mindepth 4 -type f)
[ -z "$deep" ] || { echo "gpu_session_cpu: more than two folders down: $deep"; exit 1; }
GPU_SESSION_DEST="$scratch/back" bash scripts/gpu/gpu-session.sh unpack "$scratch/out" > "$scratch/unpack.log" 2>&1 ||
  { cat "$scratch/unpack.log"; exit 1; }
[ -s "$scratch/back/train/model.spar" ] || { echo "gpu_session_cpu: unpack made no model.spar"; exit 1; }
[ -s "$scratch/back/check/report.md" ] || { echo "gpu_session_cpu: no report.md back"; exit 1; }
/usr/bin/python3 - "$scratch/back/check/out/report.json" "$scratch/out/train/steps.log" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
bad = {k: v for k, v in r["steps"].items() if v != 0}
assert not bad, f"steps that failed: {bad}"
assert len(r["tests"]) >= 20 and all(t["failures"] == 0 and t["tests"] > 0 for t in r["tests"]), r["tests"]
assert any(t["program"] == "test_coopmat" for t in r["tests"]), r["tests"]
assert any("gemm_coopmat.comp" in line for line in r["kernels"]), r["kernels"]
assert r["selftest"] == "verdict: PASS (29 of 29 checks passed)", r["selftest"]  # spar selftest in the bundle
assert r["model"]["engine_fp32"]["total"]["gpu_ms"] > 0 and r["model"]["engine_fp16"]["total"]["gpu_ms"] > 0
assert r["model"]["reference"]["modes"]["fp32"]["total_ms"] > 0
assert any(o["op"] == "gemm_f32" and o["torch_ms"] for o in r["ops"]), r["ops"]
log = open(sys.argv[2]).read()
assert "teachers from" in log and "check: exit 0, pool: exit 0" in log and "training: exit 0" in log, log
print(f"gpu-session --cpu: {len(r['steps'])} check steps, {sum(t['tests'] for t in r['tests'])} tests, "
      "report ok; training back and packed")
PY
