#!/usr/bin/env bash
# Sets everything up on a Debian machine and runs the main job on built-in example data:
# installs the dependencies, builds pbve, and runs example 1 (a rigid board edited into cloth).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
cmake --preset release >/dev/null
cmake --build --preset release --target pbve_cli
bash examples/board_to_cloth/run.sh "${1:-out/board_to_cloth}"
