#!/usr/bin/env bash
# One command for a newcomer: install dependencies, build, and run the main job: render novel
# views, motion masks and label maps with `spar render` from a shipped scene (scripts/demo/demo.sh).
# Arguments go to `spar render` (e.g. --device 0, --assume-static).
set -euo pipefail
cd "$(dirname "$0")"
bash scripts/setup/install-deps.sh
bash scripts/setup/build.sh
bash scripts/demo/demo.sh "$@"
