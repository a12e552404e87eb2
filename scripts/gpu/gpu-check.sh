#!/usr/bin/env bash
# The GPU check: the engine's tests, kernels and model against PyTorch on a lent GPU, in one call.
#
# The GPU check (issue 15), prepared here and run in one call on a machine with a GPU (the
# NVIDIA H200 the device tool lends: PyTorch + CUDA, an NVIDIA Vulkan driver, no package
# registries), in under 8 minutes, ending in one report: $OUT/report.md, report.json, steps.log
# and gpu-check-all.tar.xz (every step's log and JSON; the device tool brings back 8 files):
#
#   bash scripts/gpu/gpu-check.sh pack        # here, after the build: .gpucheck/bundle.tar.xz
#   bash scripts/gpu/gpu-check.sh run         # there, in the repository root, .gpucheck carried
#   bash scripts/gpu/gpu-check.sh run --cpu   # here: the same steps on lavapipe, small shapes
#   bash scripts/gpu/gpu-check.sh run --cpu-coopmat   # the same on lavapipe 26.1 (DIR of
#                                         # scripts/portability/coopmat-lavapipe.sh): the cooperative-matrix
#                                         # plan, its tuner and test_coopmat, as the GPU takes them
# scripts/gpu/gpu-session.sh runs `run` and issue 14's training call in one device call.
#
# The bundle holds the programs that need no image library (spar-bench, the op tests, the
# model-level tests on goldens, the cooperative-matrix tests: they link libvulkan and the C++
# runtime only) and a runtime to run them with: Debian 13's dynamic loader, C and C++ libraries,
# Vulkan loader and Khronos validation layer (1.4.309, which knows VK_KHR_cooperative_matrix),
# from scripts/portability/coopmat-lavapipe.sh's download. So nothing on that machine but its GPU driver is
# used, and every program runs under the validation layer where the tests ask for it.
# Steps of `run` (each with its own time limit; a failing step is reported, the rest go on):
#   1. spar-bench --list-kernels: the device, the kernel plan and why (the GEMM tiles measured)
#      then spar-bench --selftest: spar selftest on the device's driver (selftest.log)
#   2. the op tests and test_kernel_plan, test_coopmat (validation layer on, zero messages)
#   3. spar-bench: every op case (4096^3 GEMMs on a GPU) with the plan, JSON
#   4. gpu_reference_bench.py --ops: cuBLAS GEMM (TF32 off) and SDPA on the same GPU
#   5. the full-size model (official configuration, random weights made there, seed 11):
#      spar-bench --model fp32 and fp16, 4 inputs + 4 targets at 256x256, per stage; fp32 again
#      with inputs through texel buffers (SPAR_INPUTS=texel)
#   6. gpu_reference_bench.py on the same checkpoint and frames: fp32 eager and bf16
#   7. goldens made there (tests/python/make_spar_goldens.py) and the model-level tests
#   8. scripts/gpu/gpu_check_report.py: report.json, report.md (side by side, the issue's bars)
set -uo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd)
mode=${1:-}
shift || true

bins=(spar-bench test_linear test_attention test_conv2d test_conv_transpose2d test_norm test_reduce_channels
      test_patchify test_pool test_resize test_transformer_block test_unary test_binary test_copy2d test_rope
      test_embedding test_runtime test_count_nonfinite test_kernel_plan test_plucker_rays test_coopmat
      test_dino_v3 test_cv_drp)
op_tests=(test_linear test_attention test_conv2d test_conv_transpose2d test_norm test_reduce_channels test_patchify
          test_pool test_resize test_transformer_block test_unary test_binary test_copy2d test_rope test_embedding
          test_runtime test_count_nonfinite test_kernel_plan test_plucker_rays)
model_tests=(test_dino_v3 test_cv_drp)

if [ "$mode" = pack ]; then
  build=${SPAR_BUILD:-build}
  export DIR=${DIR:-$build/mesa-trixie}  # where scripts/portability/coopmat-lavapipe.sh keeps Debian 13's files
  trixie="$DIR/root/usr/lib/x86_64-linux-gnu"
  # libGLdispatch.so.0 (glvnd) travels too: NVIDIA's Vulkan driver, libGLX_nvidia.so.0, needs it
  # and the GPU machine's image has none (2026-12-04: without it the loader found no driver).
  [ -f "$trixie/libGLdispatch.so.0" ] || rm -f "$DIR/lvp_icd.json"  # a download from before: fetch again
  bash scripts/portability/coopmat-lavapipe.sh >/dev/null || exit 1
  stage=$(mktemp -d)
  mkdir -p "$stage/bin" "$stage/runtime" "$stage/layers"
  for b in "${bins[@]}"; do
    f=$(find "$build/bin" "$build/tests" -maxdepth 1 -type f -name "$b" | head -n 1)
    [ -n "$f" ] || { echo "gpu-check: $b not built (cmake --build $build)" >&2; exit 1; }
    if ldd "$f" | grep -q -E "OpenImageIO|libpng|libicu"; then
      echo "gpu-check: $b links an image library; it cannot travel" >&2; exit 1
    fi
    strip -o "$stage/bin/$b" "$f"
  done
  for l in ld-linux-x86-64.so.2 libc.so.6 libm.so.6 libstdc++.so.6 libgcc_s.so.1 libvulkan.so.1 libGLdispatch.so.0; do
    cp -L "$trixie/$l" "$stage/runtime/$l"
  done
  cp -L "$trixie/libVkLayer_khronos_validation.so" "$stage/layers/"
  # the manifest's relative library path is relative to the manifest
  sed 's#"library_path": *"[^"]*"#"library_path": "./libVkLayer_khronos_validation.so"#' \
    "$DIR/root/usr/share/vulkan/explicit_layer.d/VkLayer_khronos_validation.json" \
    > "$stage/layers/VkLayer_khronos_validation.json"
  mkdir -p .gpucheck
  grep -qxF '/.gpucheck/' .git/info/exclude 2>/dev/null || echo '/.gpucheck/' >> .git/info/exclude
  tar -C "$stage" -cf - bin runtime layers | xz -T2 -6 > .gpucheck/bundle.tar.xz
  git rev-parse HEAD > .gpucheck/commit
  rm -rf "$stage"
  echo "gpu-check: .gpucheck/bundle.tar.xz ($(du -h .gpucheck/bundle.tar.xz | cut -f1)) from $(cat .gpucheck/commit);"
  echo "           carry .gpucheck and run: bash scripts/gpu/gpu-check.sh run"
  exit 0
fi

if [ "$mode" != run ] || [ $# -gt 1 ] || { [ $# = 1 ] && [ "$1" != --cpu ] && [ "$1" != --cpu-coopmat ]; }; then
  echo "usage: bash scripts/gpu/gpu-check.sh pack | run [--cpu | --cpu-coopmat]" >&2
  exit 2
fi
cpu=0 coopcpu=0
[ "${1:-}" = --cpu ] && cpu=1
[ "${1:-}" = --cpu-coopmat ] && cpu=1 coopcpu=1
final=${OUT:-$root/build/gpu-check-out}
mkdir -p "$final"
work=${GPU_CHECK_WORK:-/tmp/spar-gpu-check}
rm -rf "$work" && mkdir -p "$work"
out="$work/out"  # every step's files; the report and an archive of them go to $final
mkdir -p "$out"
log="$out/steps.log"
: > "$log"
# The clock and the log line from bash itself ($EPOCHSECONDS, no `date` or `tee` process a line:
# a step logs many, and each process costs a virtual machine milliseconds).
t_start=$EPOCHSECONDS
say() { local line="[gpu-check $(( EPOCHSECONDS - t_start ))s] $*"; echo "$line" >> "$log"; echo "$line"; }

[ -f .gpucheck/bundle.tar.xz ] || { echo "gpu-check: no .gpucheck/bundle.tar.xz (run 'pack' here first)" >&2; exit 1; }
tar -C "$work" -xJf .gpucheck/bundle.tar.xz
rt="$work/runtime"
# NVIDIA's Vulkan driver: where the device README says it is, else the usual places.
libpath="$rt"
if [ $cpu = 0 ]; then
  nv=${GPU_CHECK_NVIDIA_ROOT:-}  # where / is, for the driver's files (a test's fake tree; else /)
  for icd in "${VK_DRIVER_FILES:-}" "$nv"/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json \
             "$nv"/usr/share/vulkan/icd.d/nvidia_icd.json "$nv"/etc/vulkan/icd.d/nvidia_icd.json; do
    [ -n "$icd" ] && [ -f "$icd" ] && break
  done
  nvlibs=("$nv"/usr/local/nvidia/lib64 "$nv"/usr/local/nvidia/lib "$nv"/usr/lib/x86_64-linux-gnu "$nv"/lib/x86_64-linux-gnu)
  if [ ! -f "$icd" ]; then
    # No manifest, but the driver's Vulkan library may be there (it is libGLX_nvidia): name it in
    # a manifest of our own.
    lib=$(for d in "${nvlibs[@]}"; do ls "$d"/libGLX_nvidia.so.0 2>/dev/null; done | head -n 1)
    [ -n "$lib" ] || { say "no NVIDIA Vulkan driver manifest and no libGLX_nvidia.so.0 found"; exit 1; }
    icd="$work/nvidia_icd.json"
    printf '{"file_format_version": "1.0.1", "ICD": {"library_path": "%s", "api_version": "1.3.0"}}\n' "$lib" > "$icd"
    say "no NVIDIA Vulkan driver manifest found: using $lib"
  fi
  export VK_DRIVER_FILES="$icd" VK_ICD_FILENAMES="$icd"
  for d in "${nvlibs[@]}"; do
    [ -d "$d" ] && libpath="$libpath:$d"
  done
else
  if [ $coopcpu = 1 ]; then  # Debian 13's lavapipe and its libraries, unpacked beside the build
    drv=$(cd "${DIR:-build/mesa-trixie}" 2>/dev/null && pwd)
    [ -f "$drv/lvp_icd.json" ] || { echo "gpu-check: no lavapipe 26.1 in ${DIR:-build/mesa-trixie} (bash scripts/portability/coopmat-lavapipe.sh)" >&2; exit 1; }
    export VK_ICD_FILENAMES="$drv/lvp_icd.json" VK_DRIVER_FILES="$drv/lvp_icd.json"
    libpath="$libpath:$drv/root/usr/lib/x86_64-linux-gnu"
  fi
  libpath="$libpath:/usr/lib/x86_64-linux-gnu:/lib/x86_64-linux-gnu"
fi
export VK_LAYER_PATH="$work/layers"
py=${PYTHON:-python3}
[ $cpu = 1 ] && py=${PYTHON:-/usr/bin/python3}
# the golden makers (tests/python) run as programs: the repository's Python roots
export PYTHONPATH="$(bash scripts/setup/pythonpath.sh)${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
export XDG_CACHE_HOME="$work/cache"  # the pipeline cache and kernel-choice.json of this run
# bin PROGRAM ARGS...: a program of the bundle through the bundle's loader and libraries (a
# script, so that `timeout` can run it).
cat > "$work/bin.sh" <<EOS
#!/bin/sh
b=\$1; shift
exec "$rt/ld-linux-x86-64.so.2" --library-path "$libpath" "$work/bin/\$b" "\$@"
EOS
chmod +x "$work/bin.sh"
bin="$work/bin.sh"
deadline=${GPU_CHECK_SECONDS:-480}  # steps not started by then are skipped (the call's limit is 600 s)
step() {  # step NAME SECONDS COMMAND... : runs it with a limit, its output in $out/NAME.log
  local name=$1 limit=$2; shift 2
  local left=$(( deadline - (EPOCHSECONDS - t_start) ))
  if [ "$name" != report ] && [ $left -le 10 ]; then
    say "$name: skipped (the run's $deadline s are used up)"
    echo "$name skipped" >> "$out/steps.rc"
    return 1
  fi
  [ "$name" != report ] && [ "$limit" -gt $left ] && limit=$left
  say "$name ..."
  timeout "$limit" "$@" > "$out/$name.log" 2>&1
  local rc=$?
  echo "$name $rc" >> "$out/steps.rc"
  say "$name: exit $rc ($(tail -n 1 "$out/$name.log" | cut -c1-150))"
  return $rc
}
: > "$out/steps.rc"

# --cpu-coopmat: spar-bench takes the GPU's path on this CPU device (the plan with cooperative
# matrices, its tiles measured); the tests keep their own choices.
plan=()
[ $coopcpu = 1 ] && plan=(env SPAR_KERNELS=coopmat SPAR_MEASURE_KERNELS=1)
say "device check: $($bin spar-bench --list-devices 2>&1 | tr '\n' ' ')"
step kernels 120 "${plan[@]}" $bin spar-bench --list-kernels --json
cp "$out/kernels.log" "$out/kernels.json" 2>/dev/null
# every candidate the tuner timed (old kernels beside new ones), for the report
cp "$XDG_CACHE_HOME/spar/kernel-choice.json" "$out/kernel-choice.json" 2>/dev/null
# spar selftest on the device's own driver and plan (spar-bench --selftest: the same checks as
# `spar selftest`, in a program of the bundle; the self-test model from the tree carried there):
# its table is selftest.log, exit 0 = passed.
step selftest 120 "${plan[@]}" $bin spar-bench --selftest --selftest-model-dir "$root/data/selftest"

mkdir -p "$out/tests"
# The op tests' goldens that need no model (transformer blocks, Plucker rays: CTest's fixture
# op_goldens), made there.
step op-goldens 120 "$py" tests/python/make_op_goldens.py "$work/op-goldens"
export SPAR_OP_GOLDENS_DIR="$work/op-goldens"
# The tests keep the plan's default tiles (measuring them in every test process would cost
# seconds each); spar-bench below measures, and its choice is what the timings use.
export SPAR_MEASURE_KERNELS=0
# --cpu: a quarter of each program's tests (GoogleTest's sharding: every program still runs, at
# least its first test); the CTest suite runs all of them on this device anyway.
shard=()
[ $cpu = 1 ] && shard=(GTEST_TOTAL_SHARDS=${GPU_CHECK_CPU_SHARDS:-4} GTEST_SHARD_INDEX=0)
for t in "${op_tests[@]}" test_coopmat; do
  [ $cpu = 1 ] && [ $coopcpu = 0 ] && [ $t = test_coopmat ] && continue   # lavapipe 22.3 has none
  force=()  # a CPU device takes cooperative matrices only when told (a GPU by its plan)
  [ $coopcpu = 1 ] && [ $t = test_coopmat ] && force=(SPAR_KERNELS=coopmat)
  step "test-$t" 300 env "${force[@]}" "${shard[@]}" $bin "$t" --gtest_output="json:$out/tests/$t.json"
done

unset SPAR_MEASURE_KERNELS
ops_args=(--repeat 10)                          # every case, 4096^3 GEMMs among them
[ $cpu = 1 ] && ops_args=(--repeat 2 --only _f32)
step bench-ops 300 "${plan[@]}" $bin spar-bench --json "${ops_args[@]}"
small=()
[ $cpu = 1 ] && small=(--small --repeat 3)
step reference-ops 240 "$py" scripts/gpu/gpu_reference_bench.py --ops --out "$out/reference_ops.json" "${small[@]}"

# The full-size model (or, with --cpu, the tiny configuration): checkpoint, pack, timings.
cfg=full
size=256x256
[ $cpu = 1 ] && cfg=tiny && size=""
step make-model 300 bash -c "$py -c 'import json, sys; from spar_convert.model_config import $cfg; \
json.dump($cfg().to_dict(), open(sys.argv[1], \"w\"))' '$work/model.json' && \
  $py reference/spar-reference make-checkpoint --config '$work/model.json' --seed 11 --perturb --no-optimizer \
  -o '$work/model.pt' && $py converter/spar-convert -q '$work/model.pt' --config '$work/model.json' -o '$work/model.spar' \
  --bpe text/data/clip/bpe_simple_vocab_16e6.txt.gz"
sizearg=()
[ -n "$size" ] && sizearg=(--size "$size")
reps=5
[ $cpu = 1 ] && reps=2
for p in fp32 fp16; do
  step "bench-model-$p" 300 "${plan[@]}" $bin spar-bench --model "$work/model.spar" --views 4 --targets 4 "${sizearg[@]}" \
    --precision $p --repeat $reps --json
done
# The same fp32 run with inputs through texel buffers (SPAR_INPUTS=texel): NVIDIA's plan takes
# storage buffers (its texel buffers are shorter than a storage binding); which is faster there
# was not measured before.
step bench-model-fp32-texel 300 env "${plan[@]}" SPAR_INPUTS=texel $bin spar-bench --model "$work/model.spar" --views 4 \
  --targets 4 "${sizearg[@]}" --precision fp32 --repeat $reps --json
step reference-model 420 "$py" scripts/gpu/gpu_reference_bench.py --checkpoint "$work/model.pt" --config "$work/model.json" \
  --views 4 --targets 4 "${sizearg[@]}" --repeat $reps --out "$out/reference_model.json"

# Goldens made there (PyTorch on the CPU), then the model-level tests on them.
step goldens 300 "$py" tests/python/make_spar_goldens.py "$work/goldens"
export SPAR_GOLDENS_DIR="$work/goldens" SPAR_CLIP_BPE="$root/text/data/clip/bpe_simple_vocab_16e6.txt.gz"
export SPAR_MEASURE_KERNELS=0
for t in "${model_tests[@]}"; do
  step "test-$t" 300 $bin "$t" --gtest_output="json:$out/tests/$t.json"
done

step report 60 "$py" scripts/gpu/gpu_check_report.py "$out"
say "done in $(( EPOCHSECONDS - t_start )) s: $final/report.md"
cp "$out/report.md" "$out/report.json" "$out/steps.log" "$final/" 2>/dev/null
tar -C "$work" -cf - out | xz -T2 > "$final/gpu-check-all.tar.xz"
cat "$out/report.md" 2>/dev/null
