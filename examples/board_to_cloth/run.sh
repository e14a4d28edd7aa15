#!/usr/bin/env bash
# Example 1 — board to cloth (the paper's board sequence): a rigid board held at its top edge
# and swung is edited into cloth anchored where it is held; once without control (the
# paper's unconstrained baseline) and once with control, then both reports are plotted.
# Usage: examples/board_to_cloth/run.sh [OUT_DIR]   (after building the release preset)
set -euo pipefail
source "$(dirname "$0")/../common.sh"
run_example "${1:-$root/out/board_to_cloth}" --shape board --motion swing --frames 90
