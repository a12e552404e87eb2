#!/usr/bin/env bash
# Measures a training run's held-out PSNR against its steps and minutes.
#
# Held-out PSNR of a spar-train run against its steps and minutes: every checkpoint the run kept
# (spar-train --keep-checkpoints: checkpoint_stepNNNNNN.pt, and the final checkpoint.pt) packed
# and evaluated by `spar eval` on the first SCENES test scenes (default 12; evaluation/spar_eval/
# PROTOCOL.md), one row each: step, training minutes at that step (from train_log.txt), PSNR and
# SSIM for K = 2 / 3 / 4 inputs, and the nearest-input-copy baseline on the same pixels.
#
#   bash training/learning-curve.sh RUN [SCENES]     -> RUN/curve.md, RUN/curve/*.json
set -euo pipefail
cd "$(dirname "$0")/.."
run=$1
count=${2:-12}
spar=${SPAR_BUILD:-build}/bin/spar
py=/usr/bin/python3
scenes=build/eval/test-scenes-$count
[[ -d $scenes ]] || $py scenes/spar-scenes split --split test --count "$count" --out "$scenes" >/dev/null
mkdir -p "$run/curve"
rows=()
for ck in "$run"/checkpoint_step*.pt "$run/checkpoint.pt"; do
  [[ -f $ck ]] || continue
  name=$(basename "$ck" .pt)
  [[ -f $run/curve/$name.json ]] || {
    $py converter/spar-convert -q "$ck" --config "$run/config.json" --fp16 -o "$run/curve/$name.spar"
    $spar eval --model "$run/curve/$name.spar" --scenes "$scenes" --out "$run/curve/$name.json" >/dev/null 2>&1
    rm -f "$run/curve/$name.spar"
  }
  rows+=("$run/curve/$name.json")
done
$py - "$run" "${rows[@]}" <<'PY'
import json, re, sys
run, files = sys.argv[1], sys.argv[2:]
log = open(f"{run}/train_log.txt").read()
total = int(re.search(r"(\d+) steps of", log).group(1))
rate = {int(m.group(1)): float(m.group(2)) for m in re.finditer(r"step (\d+)/\d+ .* ([0-9.]+) s/step", log)}
out = ["| step | minutes | PSNR K=2 / 3 / 4 | SSIM K=3 | copy K=3 | train PSNR (log) |", "|---|---|---|---|---|---|"]
train = {int(m.group(1)): float(m.group(2)) for m in re.finditer(r"step (\d+)/\d+ .* psnr ([0-9.]+) dB", log)}
for f in files:
    m = re.search(r"step(\d+)", f)
    step = int(m.group(1)) if m else total
    d = json.load(open(f))
    by_k = {int(k): r for k, r in d.get("results", {}).items()}
    psnr = " / ".join(f"{by_k[k]['psnr']:.2f}" for k in (2, 3, 4) if k in by_k)
    s = rate.get(step) or rate.get(max([x for x in rate if x <= step] or [0]), 0.0)
    out.append(f"| {step} | {step * s / 60:.0f} | {psnr} | {by_k.get(3, {}).get('ssim', 0):.3f} | "
               f"{by_k.get(3, {}).get('psnr_nearest_input', 0):.2f} | {train.get(step, float('nan')):.2f} |")
open(f"{run}/curve.md", "w").write("\n".join(out) + "\n")
print("\n".join(out))
PY
