#!/usr/bin/env bash
# Builds the project into ./build (Release).
# Shaders are compiled to SPIR-V and embedded at build time.
set -euo pipefail
cd "$(dirname "$0")/../.."
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release
cmake --build build -j"$(nproc)"
