#!/usr/bin/env bash
# Example 1 through Bullet — board to cloth with `engine: bullet`: the swung board of example 1
# is edited into Bullet cloth (the board's two faces simulated as one sheet) anchored where it
# is held; once without control and once with control (central differences through Bullet, one
# acceleration per cluster of at-risk vertices), then both reports are plotted.
# Usage: examples/board_to_cloth_bullet/run.sh [OUT_DIR]   (after building the release preset
# with Bullet)
set -euo pipefail
source "$(dirname "$0")/../common.sh"
run_example "${1:-$root/out/board_to_cloth_bullet}" --shape board --motion swing --frames 90 --engine bullet
