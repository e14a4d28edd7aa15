#!/usr/bin/env bash
# Example 2 — elastic figurine (the paper's puppetry effect): a character-like figurine held at
# its feet is moved sideways and stopped; edited into a soft elastic body anchored at its feet,
# it keeps moving where it is soft after the hand stops. Without and with control, then plotted.
# Usage: examples/elastic_figurine/run.sh [OUT_DIR]   (after building the release preset)
set -euo pipefail
source "$(dirname "$0")/../common.sh"
run_example "${1:-$root/out/elastic_figurine}" --shape figurine --motion stop --frames 90
