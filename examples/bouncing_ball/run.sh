#!/usr/bin/env bash
# Example 4 — bouncing ball, the failure case the paper shows (section 4.5): a rigid ball rolls
# and bounces; edited into a soft ball that falls and bounces by itself, the parts of the ball
# that the footage never shows keep turning into view. Keeping them hidden needs control forces
# that rival the physical ones, and the report says so (faithfulness warnings).
# Usage: examples/bouncing_ball/run.sh [OUT_DIR]   (after building the release preset)
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
pbve=${PBVE:-$root/build/release/bin/pbve}
out=${1:-$root/out/bouncing_ball}
mkdir -p "$out"
"$pbve" synth --shape ball --motion bounce --frames 60 "$out"
"$pbve" edit "$out/scene.yaml" --no-control -o "$out/unconstrained.mp4" --report "$out/unconstrained.json"
"$pbve" edit "$out/scene.yaml" -o "$out/edited.mp4" --report "$out/report.json"
"$pbve" plot "$out/unconstrained.json" "$out/report.json" --labels unconstrained,constrained -o "$out/plot.png"
echo
echo "edited video: $out/edited.mp4"
echo "report:       $out/report.json (see summary.warnings)"
