#!/usr/bin/env bash
# One command for a newcomer: install dependencies, build, and run the main job.
# Until the model lands, the main job is the op benchmark on the chosen Vulkan device.
set -euo pipefail
cd "$(dirname "$0")"
bash scripts/install-deps.sh
bash scripts/build.sh
./build/samples/spar-bench "$@"
