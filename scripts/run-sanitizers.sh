#!/usr/bin/env bash
# Runs the whole test suite under AddressSanitizer + UndefinedBehaviorSanitizer (GCC, the `asan`
# preset, leak detection on): installs the dependencies, configures and builds build/asan, runs
# ctest with the preset's sanitizer options (3600 s per test). On 2 cores about 80 min to build
# from scratch and 80 min to test: a separate step, not part of .ci/run. See docs/reliability.md.
#
# Usage: scripts/run-sanitizers.sh [CTEST_ARG...]   (e.g. -R Mesh to run a subset)
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
cmake --preset asan
cmake --build --preset asan
ctest --preset asan "$@"
