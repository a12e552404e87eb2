#!/bin/sh
# CTest gpu_train_cpu: scripts/gpu/gpu-train.sh as far as this CPU allows: `run --cpu` (every step of
# the GPU training call, at tiny sizes: scene pool, validation scenes, teachers, two variants in
# parallel measured on the validation scenes, the best written back), then `unpack` and the
# checks that matter for the real call: what comes back fits the device tool (at most 8 files,
# 16 MiB each), the rebuilt checkpoint and its model.spar agree (engine `spar eval` against the
# PyTorch reference), and the run's own last held-out measurement is what `spar eval` measures
# on the same scenes (up to the fp16 rounding of the weights in the checkpoint).
# Arguments: BUILD_DIR SOURCE_DIR SCRATCH_DIR.
set -eu
build=$1 src=$2 scratch=$3
rm -rf "$scratch" && mkdir -p "$scratch"
cd "$src"
OUT="$scratch/out" GPU_TRAIN_WORK="$scratch/work" bash scripts/gpu/gpu-train.sh run --cpu > "$scratch/run.log" 2>&1 ||
  { tail -n 30 "$scratch/run.log"; exit 1; }
files=$(ls "$scratch/out" | wc -l)
[ "$files" -le 8 ] || { echo "gpu_train_cpu: $files files to bring back (the device tool brings 8)"; exit 1; }
big=$(find "$scratch/out" -type f -size +16M)
[ -z "$big" ] || { echo "gpu_train_cpu: over 16 MiB: $big"; exit 1; }
bash scripts/gpu/gpu-train.sh unpack "$scratch/out" "$scratch/run"
"$build/bin/spar" eval --model "$scratch/run/model.spar" --scenes "$scratch/work/val" --views 3 \
  --out "$scratch/engine.json" > "$scratch/eval.log" 2>&1 || { cat "$scratch/eval.log"; exit 1; }
/usr/bin/python3 evaluation/spar-eval-reference --checkpoint "$scratch/run/checkpoint.pt" \
  --config "$scratch/run/config.json" --scenes "$scratch/work/val" --views 3 --quiet \
  --out "$scratch/reference.json"
/usr/bin/python3 - "$scratch" <<'PY'
import json, sys
d = sys.argv[1]
best = open(f"{d}/run/best").read().strip()
curve = [json.loads(line) for line in open(f"{d}/run/{best}/curve.jsonl")]
engine = json.load(open(f"{d}/engine.json"))["results"]["3"]
ref = json.load(open(f"{d}/reference.json"))["results"]["3"]
for key in ("psnr", "ssim", "psnr_nearest_input", "mask_miou", "sem_miou"):
    assert abs(engine[key] - ref[key]) < 1e-3, (key, engine[key], ref[key])
last = curve[-1]
assert abs(last["psnr_nearest_input"] - engine["psnr_nearest_input"]) < 1e-4  # engine: float sums
# the run measured its fp32 weights, the checkpoint holds them rounded to fp16
assert abs(last["psnr"] - engine["psnr"]) < 0.05, (last["psnr"], engine["psnr"])
print(f"gpu-train --cpu: best {best}, {last['step']} steps, held-out PSNR {last['psnr']:.3f} "
      f"(run) / {engine['psnr']:.3f} (engine) / {ref['psnr']:.3f} (reference)")
PY
