#!/usr/bin/env bash
# Builds the project into ./build (Release).
# Shaders are compiled to SPIR-V and embedded at build time.
# Meanwhile (network, not CPU) it fetches the cooperative-matrix lavapipe the coopmat tests run
# on (scripts/portability/coopmat-lavapipe.sh, into build/tests/mesa-trixie, where the
# coopmat_driver test fixture looks first): the test command then does not wait for the download
# (measured: 14.6 s of a bare clone's test command). A failed fetch only warns here; the fixture
# tries again and reports it.
set -euo pipefail
cd "$(dirname "$0")/../.."
mkdir -p build/tests
DIR=build/tests/mesa-trixie bash scripts/portability/coopmat-lavapipe.sh > build/tests/coopmat-fetch.log 2>&1 &
fetch=$!
# A new build directory: Clang and Ninja where installed (scripts/setup/install-deps.sh installs
# both for the sanitized build). Measured 2026-12-05 on 2 cores, the whole build from nothing:
# 416 s against 486-526 s with GCC and Makefiles (Clang compiles these sources about 26 % faster).
# An existing build directory keeps the generator and compiler it was configured with.
if [ ! -f build/CMakeCache.txt ] && command -v ninja > /dev/null && command -v clang++-14 > /dev/null; then
  cmake -G Ninja -S . -B build -DCMAKE_BUILD_TYPE=Release -DCMAKE_CXX_COMPILER=clang++-14 -DCMAKE_C_COMPILER=clang-14
fi
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release
cmake --build build -j"$(nproc)"
wait "$fetch" || echo "build.sh: fetching the cooperative-matrix lavapipe failed (build/tests/coopmat-fetch.log);" \
                      "the coopmat tests will try again"
