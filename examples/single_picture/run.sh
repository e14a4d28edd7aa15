#!/usr/bin/env bash
# Example 3 — single picture (paper section 4.3's single-image mode): one photo-like frame of a
# figurine is edited into a 3-second clip of the figurine wobbling as a soft elastic body under
# gravity, anchored at its feet. The background behind it is inpainted.
# Usage: examples/single_picture/run.sh [OUT_DIR]   (after building the release preset)
set -euo pipefail
source "$(dirname "$0")/../common.sh"
run_example "${1:-$root/out/single_picture}" --shape figurine --image --frames 90
