#!/usr/bin/env bash
# Builds and runs the C++ tests again under ASan and UBSan (CI's second build).
#
# The C++ tests again under AddressSanitizer + UndefinedBehaviorSanitizer (CI's second build,
# ./build-asan): the host code of the engine, model, file formats, image I/O and the `spar` CLI
# (its tests run the sanitized binary). A reduced set, for CI's time: the op and runtime tests,
# the file readers (device-limit JSON files too), the tiny-model pipeline tests, spar selftest, hostile input, non-finite values, faults and
# the --path outputs; the model tests against the PyTorch reference's full goldens and the
# benchmarks run only in the Release build. The Vulkan driver (lavapipe) and the validation
# layer are not instrumented.
#
#   bash .ci/test-sanitized.sh        (after scripts/setup/install-deps.sh)
set -euo pipefail
cd "$(dirname "$0")/.."
targets=(spar test_runtime test_linear test_attention test_conv2d test_conv_transpose2d test_norm test_unary
         test_binary test_pool test_resize test_rope test_embedding test_patchify test_copy2d test_reduce_channels
         test_count_nonfinite test_engine_options test_packed_model test_npy test_cameras test_colmap
         test_bpe_tokenizer test_image_prep test_spar_pipeline test_spar_nonfinite test_spar_hostile_input
         test_spar_faults test_spar_render_outputs test_kernel_plan test_device_limits test_spar_selftest)
# No ccache: a fresh CI machine starts with an empty cache, and this build's flags differ from
# the Release build's (measured 2026-12-03 on spar_engine + spar_model: 0 of 53 hits after the
# Release build, and a cold cache made the Release build 43 -> 48 s).
# Clang and Ninja, for CI's time (measured 2026-12-05, 2 cores, these targets from nothing):
# GCC with Makefiles 625 s, GCC with Ninja 420 s, Clang with Ninja 270 s. Makefiles build the
# targets named on one command line one after another (CMake's top Makefile is .NOTPARALLEL),
# and most test targets are one source file, so one core idled; GCC's -O1 with the sanitizers
# is 1.6x Clang's on the engine's sources. The tests take as long with either (164 s / 168 s).
# (The Release build uses Clang and Ninja too, scripts/setup/build.sh; GCC still compiles the
# installed package's example against the public headers: CTest install_and_build_example.)
# A build-asan configured otherwise before (Makefiles, GCC) cannot switch: start it again.
if [ -f build-asan/CMakeCache.txt ] && ! grep -q '^CMAKE_GENERATOR:INTERNAL=Ninja$' build-asan/CMakeCache.txt; then
  rm -rf build-asan
fi
cmake -G Ninja -S . -B build-asan -DCMAKE_CXX_COMPILER=clang++-14 -DCMAKE_C_COMPILER=clang-14 \
      -DCMAKE_BUILD_TYPE=Release -DSPAR_SANITIZE=ON -DCMAKE_CXX_FLAGS_RELEASE="-O1 -g1 -DNDEBUG"
cmake --build build-asan -j"$(nproc)" --target "${targets[@]}"
# Each test carries its executable's name as label (tests/CMakeLists.txt); fixtures they
# require (the tiny models, the goldens) are added by CTest.
labels=$(printf '%s\n' "${targets[@]}" | grep '^test_' | paste -sd'|')
# Leak checking is off: the validation layer's allocations kept until exit are reported from a
# library already unloaded (dlclose at vkDestroyInstance), which no suppression can name. Vulkan
# objects left alive are still caught: the validation layer reports them at vkDestroyDevice.
export ASAN_OPTIONS="detect_leaks=0:abort_on_error=1:strict_string_checks=1:detect_stack_use_after_return=1"
export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1"
# Left out: the long-path memory test measures peak RSS, which ASan's allocator (quarantine,
# shadow memory) inflates as it pleases (1.7 -> 4.5 GB for 8 -> 240 views, flat in Release).
export GTEST_FILTER='-*LongPathMemoryDoesNotGrowWithItsLength'
ctest --test-dir build-asan -j2 --output-on-failure -L "^(${labels})\$" |
  tee build-asan/ctest.log
