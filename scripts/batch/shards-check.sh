#!/usr/bin/env bash
# The Slurm recipe of docs/many-scenes.md run for real: the shipped scenes as a job array of `spar render --jobs --shard` and `spar eval --shard`, one task killed and requeued, the shard results merged and compared with one process over the same scenes.
#
#   SLURM_CONF=... bash scripts/batch/shards-check.sh     (scripts/batch/slurm-local.sh runs it)
#
# Exit 0 only if: every render of the array is byte-identical to the single process's, the
# merged evaluation equals the single process's (every metric and per-scene tally; times
# apart), the requeued task skipped the jobs and scenes it had finished (its log says which),
# and `spar eval --merge` refused a shard given twice. Environment: SPAR (default
# build/bin/spar), MODEL (default data/spar_rooms.spar), SCENES (default
# data/scenes), WORK (default: a temporary folder, removed at the end), REQUEUES=0
# (no requeue, no skip checks: the array's time against one process's).
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
spar=$(realpath "${SPAR:-$root/build/bin/spar}")
model=$(realpath "${MODEL:-$root/data/spar_rooms.spar}")
scenes=$(realpath "${SCENES:-$root/data/scenes}")
: "${SLURM_CONF:?SLURM_CONF must name the slurm.conf of a running cluster (scripts/batch/slurm-local.sh)}"
[ -x "$spar" ] || { echo "shards-check: no spar program at $spar (build first, or set SPAR)" >&2; exit 1; }
if [ -n "${WORK:-}" ]; then work=$WORK; mkdir -p "$work"; else work=$(mktemp -d); trap 'rm -rf "$work"' EXIT; fi
views=2,3,4
shards=2
say() { echo "shards-check: $*"; }

# Two render jobs a scene (other inputs, a camera path), in one file per side.
for side in single array; do
  mkdir -p "$work/$side"
  for s in "$scenes"/scene_*; do
    name=$(basename "$s")
    frames=$(printf '"%s",' "$s"/rgb_0{0..7}.png)
    echo "{\"frames\": [${frames%,}], \"inputs\": \"0,4,7\", \"out\": \"${name}_a\"}"
    echo "{\"frames\": [${frames%,}], \"inputs\": \"0,7\", \"out\": \"${name}_b\", \"path\": 4}"
  done > "$work/$side/jobs.jsonl"
done
jobs=$(grep -c . "$work/single/jobs.jsonl")

# One process over everything: what the array must reproduce.
t0=$(date +%s.%N)
"$spar" render --model "$model" --jobs "$work/single/jobs.jsonl" 2> "$work/single/render.log"
t1=$(date +%s.%N)
"$spar" eval --model "$model" --scenes "$scenes" --views $views --out "$work/single/eval.json" > /dev/null 2> "$work/single/eval.log"
t2=$(date +%s.%N)

# The array, as docs/many-scenes.md writes it (one device each: here the CPU's lavapipe).
cat > "$work/array/task.sh" << TASK
#!/bin/bash
#SBATCH --array=0-$((shards - 1)) --requeue --open-mode=append --cpus-per-task=1
#SBATCH --output=$work/array/task_%a.log --job-name=spar-shards
set -e
"$spar" render --model "$model" --jobs "$work/array/jobs.jsonl" --shard \${SLURM_ARRAY_TASK_ID}/$shards
"$spar" eval --model "$model" --scenes "$scenes" --views $views --shard \${SLURM_ARRAY_TASK_ID}/$shards \\
             --out "$work/array/eval_\${SLURM_ARRAY_TASK_ID}.json"
echo "task \${SLURM_ARRAY_TASK_ID} done (restart count \${SLURM_RESTART_COUNT:-0})"
TASK
t3=$(date +%s.%N)
job=$(sbatch --parsable --chdir="$work/array" "$work/array/task.sh")
say "submitted array job $job ($shards tasks, $jobs render jobs, $(ls -d "$scenes"/scene_* | wc -l) scenes, K=$views)"

# Task 0 is killed twice by Slurm's requeue: once after its first render job finished, once
# after its first scene's evaluation was kept; each time it starts over from the same command.
first_job=$(ls -d "$scenes"/scene_* | head -n 1 | xargs basename)_a
first_scene=$(ls -d "$scenes"/scene_* | head -n 1 | xargs basename)
wait_for() {  # PATH: until it exists (30 s at most)
  for _ in $(seq 3000); do [ -e "$1" ] && return 0; sleep 0.01; done
  return 1
}
queue() {  # squeue ARGS..., asked again while the controller does not answer
  local out
  for _ in $(seq 50); do
    if out=$(squeue -h "$@" 2> "$work/squeue.err"); then printf '%s' "$out"; return 0; fi
    grep -q "Invalid job id" "$work/squeue.err" && return 0  # ended and purged: not queued
    sleep 0.2
  done
  say "FAIL: squeue got no answer for 10 s"; exit 1
}
requeue() {
  scontrol requeue "${job}_0"
  # Slurm holds a requeued batch job back (its begin time, two minutes on): start it in 2 s
  # (sooner, a start in the second of the kill meets its revoked credential and fails). The
  # begin time is set once the killed task has ended, so ask until the task runs again.
  local state stopped=0 moved=0
  for i in $(seq 300); do
    state=$(queue -j "${job}_0" -o "%T %r")
    case "$state" in
      "PENDING BeginTime")  # once (each update moves it on), again after 5 s
        stopped=1
        if [ $moved = 0 ] || [ $((i - moved)) -gt 50 ]; then
          scontrol update jobid="${job}_0" StartTime=now+2 2> /dev/null && moved=$i
        fi ;;
      RUNNING*) [ $stopped = 1 ] && return 0 ;;  # running again (not yet stopped: wait)
      "") return 0 ;;
      *) stopped=1 ;;  # completing, or pending for another reason
    esac
    sleep 0.1
  done
  say "FAIL: the requeued task did not start again in 30 s"; scancel "$job"; exit 1
}
requeues=${REQUEUES:-2}
if [ "$requeues" != 0 ]; then
  wait_for "$work/array/$first_job" || { say "FAIL: task 0 rendered nothing in 30 s"; scancel "$job"; exit 1; }
  requeue
  say "requeued task 0 after its first render job ($first_job)"
  wait_for "$work/array/eval_0.json.partial/$first_scene.json" ||
    { say "FAIL: task 0 kept no evaluated scene in 30 s"; scancel "$job"; exit 1; }
  requeue
  say "requeued task 0 after its first evaluated scene ($first_scene)"
fi
for _ in $(seq 1200); do [ -z "$(queue -j "$job")" ] && break; sleep 0.5; done
t4=$(date +%s.%N)
[ -z "$(queue -j "$job")" ] || { say "FAIL: the array did not finish in 10 minutes"; scancel "$job"; exit 1; }

fail=0
for t in $(seq 0 $((shards - 1))); do
  grep -q "task $t done" "$work/array/task_$t.log" || { say "FAIL: task $t did not finish (task_$t.log)"; fail=1; }
done
# The requeued task: its log holds three starts; the later ones skipped what was done.
[ "$requeues" = 0 ] || grep -q "$first_job exists: skipped" "$work/array/task_0.log" ||
  { say "FAIL: the requeued task did not skip the job it had finished"; fail=1; }
[ "$requeues" = 0 ] || grep -q "$first_scene was finished by an earlier run" "$work/array/task_0.log" ||
  { say "FAIL: the requeued task did not skip the scene it had finished"; fail=1; }
skipped=$(grep -c "exists: skipped" "$work/array/task_0.log" || true)
say "task 0 started $(grep -c "^spar: job 1/" "$work/array/task_0.log" || true) times, skipped $skipped finished render jobs"

# Renders: byte for byte, every file but report.json (times, paths) and the page (paths).
while read -r out; do
  if ! diff -r -q -x report.json -x index.html "$work/single/$out" "$work/array/$out" > /dev/null; then
    say "FAIL: $out differs between the array and the single process"; fail=1
  fi
done < <(sed -n 's/.*"out": "\([^"]*\)".*/\1/p' "$work/single/jobs.jsonl")

# Evaluation: merged from the shards, equal to the single process's but for times.
"$spar" eval --merge $(for t in $(seq 0 $((shards - 1))); do echo "$work/array/eval_$t.json"; done) \
  --out "$work/array/merged.json" > /dev/null
python3 - "$work/single/eval.json" "$work/array/merged.json" << 'PY' || fail=1
import json, sys
timing = {"seconds", "ms_per_scene", "model_ms"}
def strip(x):
    if isinstance(x, dict):
        return {k: strip(v) for k, v in x.items() if k not in timing}
    if isinstance(x, list):
        return [strip(v) for v in x]
    return x
one, merged = (json.load(open(p)) for p in sys.argv[1:])
for key in ("results", "tallies", "scene_names", "scenes", "set_scenes", "model_digest", "views", "precision", "mode"):
    if strip(one[key]) != strip(merged[key]):
        print("shards-check: FAIL: the merged %s differs from the single process's" % key)
        sys.exit(1)
print("shards-check: merged result equals the single process's (%d scenes; K=%s PSNR %.4f dB, mask mIoU %s)"
      % (merged["scenes"], min(merged["results"]), merged["results"][min(merged["results"])]["psnr"],
         merged["results"][min(merged["results"])]["mask_miou"]))
PY
if "$spar" eval --merge "$work/array/eval_0.json" "$work/array/eval_0.json" --out "$work/array/twice.json" 2> "$work/twice.err"; then
  say "FAIL: a shard given twice was merged"; fail=1
else
  say "refused as it must: $(cat "$work/twice.err")"
fi

printf 'shards-check: single process: render %.1f s, eval %.1f s; the array (%d tasks, %d requeues), submission to the last task: %.1f s\n' \
  "$(echo "$t1 - $t0" | bc)" "$(echo "$t2 - $t1" | bc)" "$shards" "$requeues" "$(echo "$t4 - $t3" | bc)"
[ $fail = 0 ] && say "PASS" || say "FAIL"
exit $fail
