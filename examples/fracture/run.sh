#!/usr/bin/env bash
# Example 6 — fracture from a single picture (the paper's shattering statue): one picture of a
# stone block caught falling is edited into the block breaking into 8 Voronoi pieces
# (`object.fracture`) that land and scatter as Bullet rigid bodies; once without control and
# once with control keeping the faces the picture never saw turned away. Cut faces are drawn in
# a uniform colour.
# Usage: examples/fracture/run.sh [OUT_DIR]   (after building the release preset with Bullet)
set -euo pipefail
source "$(dirname "$0")/../common.sh"
run_example "${1:-$root/out/fracture}" --shape statue --motion still --image --frames 60
