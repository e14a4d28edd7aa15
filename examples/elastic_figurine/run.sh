#!/usr/bin/env bash
# Example 2 — elastic figurine (the paper's puppetry effect): a character-like figurine held at
# its feet is pushed towards the camera and stopped, again and again; edited into an elastic body
# with a jelly belly (a soft region of its lattice) anchored at its feet, it nods over the belly
# at every stop, showing the top of its head that the footage never shows; without control the
# nods grow until it folds over, with control it stands back up. Both runs, then plotted.
# Usage: examples/elastic_figurine/run.sh [OUT_DIR]   (after building the release preset)
set -euo pipefail
source "$(dirname "$0")/../common.sh"
run_example "${1:-$root/out/elastic_figurine}" --shape figurine --motion push --frames 90
