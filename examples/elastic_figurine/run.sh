#!/usr/bin/env bash
# Example 2 — elastic figurine (the paper's puppetry effect): a character-like figurine held at
# its feet is moved sideways and stopped; edited into a soft elastic body anchored at its feet,
# it keeps moving where it is soft after the hand stops. Without and with control, then plotted.
# Usage: examples/elastic_figurine/run.sh [OUT_DIR]   (after building the release preset)
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
pbve=${PBVE:-$root/build/release/bin/pbve}
out=${1:-$root/out/elastic_figurine}
mkdir -p "$out"
"$pbve" synth --shape figurine --motion stop --frames 90 "$out"
"$pbve" edit "$out/scene.yaml" --no-control -o "$out/unconstrained.mp4" --report "$out/unconstrained.json"
"$pbve" edit "$out/scene.yaml" -o "$out/edited.mp4" --report "$out/report.json"
"$pbve" plot "$out/unconstrained.json" "$out/report.json" --labels unconstrained,constrained -o "$out/plot.png"
echo
echo "edited video: $out/edited.mp4"
echo "report:       $out/report.json"
echo "plot:         $out/plot.png"
