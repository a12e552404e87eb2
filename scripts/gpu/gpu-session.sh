#!/usr/bin/env bash
# The one device call of a session with a GPU: the GPU check and the training call together.
#
# One device call for both GPU issues: issue 15's check (scripts/gpu/gpu-check.sh) and issue 14's
# training (scripts/gpu/gpu-train.sh), in one call of under 10 minutes, because a session that draws
# the H200 has 15 minutes of it in all (start included) and two calls of this size do not fit.
#
#   bash scripts/gpu/gpu-session.sh pack          # here, after the build: .gpucheck/ (the check's
#                                             # bundle, and the CPU recipe's teacher.pt)
#   bash scripts/gpu/gpu-session.sh run           # there, .gpucheck carried; timeout_s 600
#   bash scripts/gpu/gpu-session.sh run --cpu     # here: the same sequence on lavapipe / the CPU
#   bash scripts/gpu/gpu-session.sh unpack DIR    # here: DIR = what came back -> build/gpu-session/
#
# `run`, on a machine of 8 cores or more: the check runs on cores 0-3 while the training's scene
# pool is rendered on the others (the pool needs no GPU, and the check's timings are GPU time
# or single-threaded launches, so neither disturbs the other's figures much); then the training
# gets the GPU and what is left of GPU_SESSION_SECONDS (560; the call's limit is 600 s). The
# check is held to GPU_SESSION_CHECK_SECONDS (260: steps not started by then are skipped and
# reported as such). The teacher (frozen text encoder and LSeg) comes from `pack`, which makes
# it exactly as the CPU recipe does (same seed, same 400-scene pool), so the GPU's time goes to
# SPAR alone. Under $OUT: check/report.md, check/gpu-check-all.tar.xz (report.json and every
# step's log inside), train/ (weights in parts, runs.tar.gz, summary.md, steps.log): at most the
# 8 files the device tool brings back.
set -uo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd)
mode=${1:-}
shift || true

if [ "$mode" = pack ]; then
  bash scripts/gpu/gpu-check.sh pack || exit 1
  if [ ! -f .gpucheck/teacher.pt ]; then
    # The CPU recipe's teacher: spar-train's defaults (seed, pool of 400, 300 LSeg steps, two
    # threads), one SPAR step; only teacher.pt is kept (the pool's cache stays in build/).
    tmp=$(mktemp -d)
    /usr/bin/python3 training/spar-train --out "$tmp/run" --cache "${SPAR_BUILD:-build}/scene-cache" \
      --steps 1 --save-every 0 --no-pack > "$tmp/log" 2>&1 || { tail -n 20 "$tmp/log"; exit 1; }
    cp "$tmp/run/teacher.pt" .gpucheck/teacher.pt && grep -i "teacher\|text encoder" "$tmp/log"
    rm -rf "$tmp"
  fi
  echo "gpu-session: carry .gpucheck ($(du -sh .gpucheck | cut -f1)) and run: bash scripts/gpu/gpu-session.sh run"
  exit 0
fi

if [ "$mode" = unpack ]; then
  from=${1:?usage: gpu-session.sh unpack DIR}
  dest=${GPU_SESSION_DEST:-build/gpu-session}
  mkdir -p "$dest/check"
  cp "$from"/check/* "$dest/check/" 2>/dev/null
  [ -f "$dest/check/gpu-check-all.tar.xz" ] && tar -C "$dest/check" -xJf "$dest/check/gpu-check-all.tar.xz"
  echo "gpu-session: the check's report: $dest/check/report.md"
  bash scripts/gpu/gpu-train.sh unpack "$from/train" "$dest/train"
  exit $?
fi

if [ "$mode" != run ] || [ $# -gt 1 ] || [ "${1:---cpu}" != --cpu ]; then  # nothing written yet
  echo "usage: bash scripts/gpu/gpu-session.sh pack | run [--cpu] | unpack DIR" >&2
  exit 2
fi
cpu=0
[ "${1:-}" = --cpu ] && cpu=1
out=${OUT:-$root/build/gpu-session-out}
mkdir -p "$out/check" "$out/train"
t0=$EPOCHSECONDS  # bash's clock: no `date` process a line (nor `tee`)
say() { local line="[gpu-session $(( EPOCHSECONDS - t0 ))s] $*"; echo "$line" >> "$out/train/steps.log"; echo "$line"; }
deadline=${GPU_SESSION_SECONDS:-560}
check_seconds=${GPU_SESSION_CHECK_SECONDS:-260}
teacher=${GPU_SESSION_TEACHER:-$root/.gpucheck/teacher.pt}  # the rehearsal passes a tiny one
[ -f "$teacher" ] || { echo "gpu-session: no $teacher (run 'pack' here first)" >&2; exit 1; }

# Which cores each half gets: four for the check, the rest for the pool, where there are 8 or
# more; else one after the other (this CPU: the rehearsal). GPU_SESSION_OVERLAP=1 overlaps them
# anyway (one core for the check), to try that path on a small machine.
cores=$(nproc)
overlap=${GPU_SESSION_OVERLAP:-0}
if [ "$cores" -ge 8 ]; then overlap=1; fi
command -v taskset >/dev/null || overlap=0
check_cores=4
[ "$cores" -lt 8 ] && check_cores=1
check_args=(run)
train_args=()
[ $cpu = 1 ] && check_args=(run --cpu-coopmat) train_args=(--cpu)
export GPU_TRAIN_WORK=${GPU_TRAIN_WORK:-/tmp/spar-gpu-train}
if [ $overlap = 1 ]; then
  OUT="$out/train" taskset -c "$check_cores-$((cores - 1))" bash scripts/gpu/gpu-train.sh pool "${train_args[@]}" \
    > "$out/pool.stdout" 2>&1 &
  pool_pid=$!
  OUT="$out/check" GPU_CHECK_SECONDS=$check_seconds OMP_NUM_THREADS=$check_cores taskset -c "0-$((check_cores - 1))" \
    bash scripts/gpu/gpu-check.sh "${check_args[@]}" > "$out/check.stdout" 2>&1
  check_rc=$?
  wait $pool_pid
  pool_rc=$?
else
  OUT="$out/check" GPU_CHECK_SECONDS=$check_seconds bash scripts/gpu/gpu-check.sh "${check_args[@]}" \
    > "$out/check.stdout" 2>&1
  check_rc=$?
  OUT="$out/train" bash scripts/gpu/gpu-train.sh pool "${train_args[@]}" > "$out/pool.stdout" 2>&1
  pool_rc=$?
fi
say "check: exit $check_rc, pool: exit $pool_rc (cores $cores, overlapped: $overlap)"
[ $pool_rc = 0 ] || tail -n 5 "$out/pool.stdout" | tee -a "$out/train/steps.log"
# The check's report.json and steps.log are in its archive: fewer files to bring back.
rm -f "$out/check/report.json" "$out/check/steps.log"

left=$(( deadline - (EPOCHSECONDS - t0) ))
say "training with $left s left"
OUT="$out/train" GPU_TRAIN_SECONDS=$left GPU_TRAIN_TEACHER="$teacher" \
  bash scripts/gpu/gpu-train.sh run "${train_args[@]}" > "$out/train.stdout" 2>&1
train_rc=$?
say "training: exit $train_rc"
[ $train_rc = 0 ] || tail -n 5 "$out/train.stdout" | tee -a "$out/train/steps.log"
# A part's own output comes back only where it failed (else its logs above hold all of it).
[ $check_rc = 0 ] && rm -f "$out/check.stdout"
[ $pool_rc = 0 ] && rm -f "$out/pool.stdout"
[ $train_rc = 0 ] && rm -f "$out/train.stdout"
say "done in $(( EPOCHSECONDS - t0 )) s: $(cd "$out" && find . -type f | sort | tr '\n' ' ')"
cat "$out/check/report.md" "$out/train/summary.md" 2>/dev/null
[ $check_rc = 0 ] && [ $train_rc = 0 ]
