#!/usr/bin/env bash
# Example 3 — single picture (paper section 4.3's single-image mode): one photo-like frame of a
# figurine is edited into a 3-second clip of the figurine wobbling as a soft elastic body under
# gravity, anchored at its feet. The background behind it is inpainted.
# Usage: examples/single_picture/run.sh [OUT_DIR]   (after building the release preset)
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
pbve=${PBVE:-$root/build/release/bin/pbve}
out=${1:-$root/out/single_picture}
mkdir -p "$out"
"$pbve" synth --shape figurine --image --frames 90 "$out"
"$pbve" edit "$out/scene.yaml" --no-control -o "$out/unconstrained.mp4" --report "$out/unconstrained.json"
"$pbve" edit "$out/scene.yaml" -o "$out/edited.mp4" --report "$out/report.json"
"$pbve" plot "$out/unconstrained.json" "$out/report.json" --labels unconstrained,constrained -o "$out/plot.png"
echo
echo "input picture: $out/picture.png"
echo "edited video:  $out/edited.mp4"
echo "report:        $out/report.json"
