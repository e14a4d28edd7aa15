#!/usr/bin/env bash
# Example 4 — bouncing ball, the failure case the paper shows (section 4.5): a rigid ball rolls
# and bounces; edited into a soft ball that falls and bounces by itself, the parts of the ball
# that the footage never shows keep turning into view. Keeping them hidden needs control forces
# that rival the physical ones, and the report says so (faithfulness warnings).
# Usage: examples/bouncing_ball/run.sh [OUT_DIR]   (after building the release preset)
set -euo pipefail
source "$(dirname "$0")/../common.sh"
run_example "${1:-$root/out/bouncing_ball}" --shape ball --motion bounce --frames 60
