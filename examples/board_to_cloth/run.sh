#!/usr/bin/env bash
# Example 1 — board to cloth (the paper's board sequence): a rigid board held at its top edge
# and swung is edited into cloth anchored where it is held; once without control (the
# paper's unconstrained baseline) and once with control, then both reports are plotted.
# Usage: examples/board_to_cloth/run.sh [OUT_DIR]   (after building the release preset)
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
pbve=${PBVE:-$root/build/release/bin/pbve}
out=${1:-$root/out/board_to_cloth}
mkdir -p "$out"
"$pbve" synth --shape board --motion swing --frames 60 "$out"
"$pbve" edit "$out/scene.yaml" --no-control -o "$out/unconstrained.mp4" --report "$out/unconstrained.json"
"$pbve" edit "$out/scene.yaml" -o "$out/edited.mp4" --report "$out/report.json"
"$pbve" plot "$out/unconstrained.json" "$out/report.json" --labels unconstrained,constrained -o "$out/plot.png"
echo
echo "input clip:           $out/clip.mp4"
echo "edited video:         $out/edited.mp4"
echo "report:               $out/report.json"
echo "plot:                 $out/plot.png"
echo "unconstrained video:  $out/unconstrained.mp4"
