#!/usr/bin/env bash
# Sets everything up on a Debian machine and runs the test suite:
# installs the dependencies, configures the release preset, builds, runs ctest.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
cmake --preset release
cmake --build --preset release
ctest --preset release
