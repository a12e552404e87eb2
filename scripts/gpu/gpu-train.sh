#!/usr/bin/env bash
# Trains the shipped model on a lent GPU in one call (prepared and rehearsed here).
#
# Training the shipped model on a GPU (issue 14), prepared and rehearsed here, run in one call on
# a machine with an NVIDIA GPU (the H200 the device tool lends: PyTorch + CUDA, 16 cores, no
# package registries). Nothing is carried but the repository: the scenes, the teacher and the
# model are all made there by spar-train, from the same seeds as on the CPU.
#
#   bash scripts/gpu/gpu-train.sh run            # there, in the repository root: writes $OUT
#   bash scripts/gpu/gpu-train.sh run --cpu      # here: the same steps on the CPU, tiny sizes
#   bash scripts/gpu/gpu-train.sh pool [--cpu]   # step (1) alone, for a caller that renders the pool
#                                            # while the GPU does other work; `run` then reuses it
#   bash scripts/gpu/gpu-train.sh unpack DIR RUN # here: DIR = what came back; RUN gets checkpoint.pt
#                                            # (official layout), config.json, model.spar, logs
#
# `run`: (1) the scene pool (GPU_TRAIN_SCENES train seeds, rendered on every core), 12
# validation scenes (test split, seeds after the 12 the evaluation uses: the variants are chosen
# on these, never on the evaluation's) and (2) the text and LSeg teachers, once; (3) the recipe's
# variants below in parallel on the one GPU (a model this small should leave it mostly idle,
# each process bound by its own kernel launches; if not, they share it and each fits fewer
# steps), each fitted to GPU_TRAIN_MINUTES (or what is left of GPU_TRAIN_SECONDS, 560, from
# the start of the call) by spar-train --minutes and measured on the validation scenes every
# GPU_TRAIN_EVAL_EVERY steps (held-out PSNR, copy and mean-colour baselines, mIoU against steps
# and minutes: curve.jsonl);
# (4) the variant with the best final validation PSNR written back: its weights (fp16; they are
# fp16-rounded already, so exact) in parts under the device tool's 16 MiB a file, every
# variant's log and curve, and summary.md. `unpack` rebuilds the official-layout checkpoint
# (without optimizer state: the moments stay there) and packs model.spar with spar-convert;
# then `spar eval` or `bash evaluation/evaluate.sh RUN` gives the numbers on the 12 test scenes.
# On the device: run with timeout_s 600; every step appends to $OUT/steps.log.
# GPU_TRAIN_TEACHER=FILE: a teacher.pt made beforehand (scripts/gpu/gpu-session.sh pack makes the CPU
# recipe's own) instead of step (2).
set -uo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd)
mode=${1:-}
shift || true

# name | spar-train options (besides the shared ones). The CPU recipe is batch 2, lr 6e-4;
# on a GPU a step of 16 scenes costs about what one of 2 does, so the variants spend it on
# larger batches; one adds the camera loss (known cameras from the generator), one a scene
# latent of three views' patches (192 tokens) as the official model keeps (768 at 256x256)
# instead of the CPU recipe's one view (64): the latent every novel view is decoded from.
variants=(
  "b8-lr6e-4|--batch 8 --lr 6e-4 --warmup 100"
  "b16-lr1e-3|--batch 16 --lr 1e-3 --warmup 200"
  "b16-lr1e-3-pose|--batch 16 --lr 1e-3 --warmup 200 --pose-loss 1"
  "b32-lr1.5e-3|--batch 32 --lr 1.5e-3 --warmup 200"
  "b16-lr1e-3-st192|--batch 16 --lr 1e-3 --warmup 200 --scene-tokens 192"
)

if [ "$mode" = unpack ]; then
  from=${1:?usage: gpu-train.sh unpack DIR RUN}
  run=${2:?usage: gpu-train.sh unpack DIR RUN}
  mkdir -p "$run"
  cat "$from"/weights.pt.part-* > "$run/weights.pt" || exit 1
  tar -C "$run" -xzf "$from/runs.tar.gz" || exit 1
  cp "$from/summary.md" "$run/" 2>/dev/null
  /usr/bin/python3 - "$run" <<'PY' || exit 1
import os, sys, torch
run = sys.argv[1]
w = torch.load(os.path.join(run, "weights.pt"))
ck = {"model": {k: (v.float() if v.is_floating_point() else v) for k, v in w["model"].items()},
      "optimizer": {"state": {}, "param_groups": []}, "lr_scheduler": w["lr_scheduler"],
      "fwdbwd_pass_step": w["step"], "param_update_step": w["step"]}
torch.save(ck, os.path.join(run, "checkpoint.pt"))
os.remove(os.path.join(run, "weights.pt"))
print(f"gpu-train: {run}/checkpoint.pt ({w['variant']}, {w['step']} steps)")
PY
  best=$(cat "$run/best")
  cp "$run/$best/config.json" "$run/config.json" && cp "$run/$best/train_log.txt" "$run/train_log.txt" || exit 1
  /usr/bin/python3 converter/spar-convert -q "$run/checkpoint.pt" --config "$run/config.json" --fp16 \
    --bpe text/data/clip/bpe_simple_vocab_16e6.txt.gz -o "$run/model.spar" || exit 1
  echo "gpu-train: $run/model.spar; evaluate: build/bin/spar eval --model $run/model.spar --scenes DIR"
  exit 0
fi

if { [ "$mode" != run ] && [ "$mode" != pool ]; } || [ $# -gt 1 ] || [ "${1:---cpu}" != --cpu ]; then
  echo "usage: bash scripts/gpu/gpu-train.sh run [--cpu] | pool [--cpu] | unpack DIR RUN" >&2
  exit 2
fi

cpu=0
[ "${1:-}" = --cpu ] && cpu=1
out=${OUT:-$root/build/gpu-train-out}
mkdir -p "$out"
work=${GPU_TRAIN_WORK:-/tmp/spar-gpu-train}
log=$out/steps.log
# `run` after `pool` keeps the pool (and the log so far); anything else starts afresh.
if [ "$mode" = pool ] || [ ! -f "$work/pool-ready" ]; then
  rm -rf "$work"
  : > "$log"
fi
mkdir -p "$work"
# The time of day from bash's printf: no `date` process a line (nor `tee`).
say() { local line; printf -v line '[%(%H:%M:%S)T] %s' -1 "$*"; echo "$line" >> "$log"; echo "$line"; }
py=python3                                      # there: the python3 that holds PyTorch
[ $cpu = 1 ] && py=/usr/bin/python3
export PYTHONUNBUFFERED=1
cores=$(nproc)
if [ $cpu = 1 ]; then
  # a rehearsal of every step at a size that takes a minute or two on two cores
  scenes=${GPU_TRAIN_SCENES:-8}; minutes=${GPU_TRAIN_MINUTES:-0.4}; every=${GPU_TRAIN_EVAL_EVERY:-5}
  val=2; lseg=5; device=cpu; threads=1
  variants=("${variants[0]/--batch 8/--batch 2}" "${variants[4]/--batch 16/--batch 2}")
else
  scenes=${GPU_TRAIN_SCENES:-2000}; minutes=${GPU_TRAIN_MINUTES:-5.5}; every=${GPU_TRAIN_EVAL_EVERY:-250}
  val=12; lseg=300; device=cuda; threads=2
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader >>"$log" 2>&1
fi
$py -c "import torch, numpy; print('torch', torch.__version__, 'numpy', numpy.__version__, 'cuda', torch.cuda.is_available())" \
  2>&1 | tee -a "$log"

# (1) the scene pool, once, on every core (every core this process may use); validation scenes
t0=$EPOCHSECONDS
deadline=${GPU_TRAIN_SECONDS:-560}
if [ ! -f "$work/pool-ready" ]; then
  PYTHONPATH="$(bash scripts/setup/pythonpath.sh)" $py -c "
import sys
from spar_train.data import ScenePool
ScenePool($scenes, 8, 128, '$work/scene-cache', workers=$cores, log=print)
" >>"$log" 2>&1 || { say "scene pool failed"; tail -n 20 "$log"; exit 1; }
  $py scenes/spar-scenes split --split test --count $val --start 12 --out "$work/val" >>"$log" 2>&1 \
    || { say "validation scenes failed"; exit 1; }
  say "scene pool of $scenes and $val validation scenes in $(( EPOCHSECONDS - t0 )) s on $cores cores"
  echo "$scenes" > "$work/pool-ready"
fi
[ "$mode" = pool ] && exit 0
[ "$(cat "$work/pool-ready")" = "$scenes" ] || { say "the pool in $work is not of $scenes scenes"; exit 1; }

# (2) the teachers, once (a one-step run that keeps its teacher.pt), unless one is given
common=(--scenes "$scenes" --cache "$work/scene-cache" --device "$device" --threads "$threads"
        --no-pack --save-every 0 --log-every 25)
mkdir -p "$work/teacher"
if [ -n "${GPU_TRAIN_TEACHER:-}" ]; then
  cp "$GPU_TRAIN_TEACHER" "$work/teacher/teacher.pt" || { say "no teacher at $GPU_TRAIN_TEACHER"; exit 1; }
  say "teachers from $GPU_TRAIN_TEACHER"
else
  $py training/spar-train --out "$work/teacher" "${common[@]}" --steps 1 --lseg-steps $lseg \
    >>"$log" 2>&1 || { say "teacher failed"; tail -n 20 "$log"; exit 1; }
  say "teachers in $(( EPOCHSECONDS - t0 )) s"
fi

# (3) the variants, in parallel, fitted to what is left of GPU_TRAIN_SECONDS (the call's limit
# is 600 s): 60 s kept for writing back and a 10 % overrun
left=$(( deadline - (EPOCHSECONDS - t0) - 60 ))
minutes=$(awk -v m="$minutes" -v l="$left" 'BEGIN { x = l / 66.0; if (x < m) m = x; if (m < 0.2) m = 0.2; printf "%.2f", m }')
say "training $((${#variants[@]})) variants for $minutes min each"
pids=()
for v in "${variants[@]}"; do
  name=${v%%|*}
  # shellcheck disable=SC2206
  opts=(${v#*|})
  $py training/spar-train --out "$work/$name" "${common[@]}" --teacher "$work/teacher/teacher.pt" \
    --steps 100000 --minutes "$minutes" --eval-scenes "$work/val" --eval-every "$every" "${opts[@]}" \
    > "$work/$name.stdout" 2>&1 &
  pids+=($!)
done
failed=0
for i in "${!pids[@]}"; do
  wait "${pids[$i]}" || { failed=1; say "variant ${variants[$i]%%|*} failed: $(tail -n 3 "$work/${variants[$i]%%|*}.stdout")"; }
done
say "variants done in $(( EPOCHSECONDS - t0 )) s"

# (4) the best on the validation scenes, written back
$py - "$work" "$out" "${variants[@]}" <<'PY' 2>&1 | tee -a "$log"
import json, os, sys, torch
work, out, variants = sys.argv[1], sys.argv[2], [v.split("|")[0] for v in sys.argv[3:]]
rows, best = [], None
for name in variants:
    path = os.path.join(work, name, "curve.jsonl")
    if not os.path.isfile(os.path.join(work, name, "checkpoint.pt")) or not os.path.isfile(path):
        rows.append(f"| {name} | failed | | | | | |")
        continue
    curve = [json.loads(l) for l in open(path)]
    last = curve[-1]
    f = lambda v: "n/a" if v is None else f"{v:.3f}"
    rows.append(f"| {name} | {last['step']} | {last['minutes']:.1f} | {last['psnr']:.2f} | "
                f"{last['psnr_nearest_input']:.2f} | {f(last['ssim'])} | {f(last['sem_miou'])} / {f(last['mask_miou'])} |")
    if best is None or last["psnr"] > best[1]:
        best = (name, last["psnr"])
md = ["| variant | steps | minutes | val PSNR | copy | SSIM | sem / mask mIoU |", "|---|---|---|---|---|---|---|"] + rows
if best is None:
    print("\n".join(md)); sys.exit("gpu-train: no variant finished")
md.append(f"\nbest on the validation scenes: {best[0]}")
open(os.path.join(out, "summary.md"), "w").write("\n".join(md) + "\n")
print("\n".join(md))
ck = torch.load(os.path.join(work, best[0], "checkpoint.pt"), map_location="cpu", weights_only=False)
w = {"model": {k: (v.half() if v.is_floating_point() else v) for k, v in ck["model"].items()},
     "lr_scheduler": ck["lr_scheduler"], "step": ck["param_update_step"], "variant": best[0]}
torch.save(w, os.path.join(work, "weights.pt"))
open(os.path.join(work, "best"), "w").write(best[0])
PY
[ -f "$work/weights.pt" ] || exit 1
split -b 15M -d "$work/weights.pt" "$out/weights.pt.part-"
(cd "$work" && tar -czf "$out/runs.tar.gz" best ./*.stdout \
  $(for v in "${variants[@]}"; do n=${v%%|*}; echo "$n/train_log.txt $n/curve.jsonl $n/config.json"; done))
say "written back: $(ls "$out" | tr '\n' ' ')"
exit $failed
