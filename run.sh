#!/usr/bin/env bash
# One command for a newcomer: install dependencies, build, and run the main job: render novel
# views with `spar render` from the sample photos in samples/data/room/ (scripts/demo.sh).
# Arguments go to `spar render` (e.g. --device 0, --assume-static).
set -euo pipefail
cd "$(dirname "$0")"
bash scripts/install-deps.sh
bash scripts/build.sh
bash scripts/demo.sh "$@"
