#!/usr/bin/env bash
# Installs the build tree BUILD_DIR into a temporary prefix, then configures, builds and runs a
# separate consumer project that finds pbve with find_package(pbve REQUIRED).
# Usage: check_install.sh BUILD_DIR [CMAKE_ARG...]   (extra arguments configure the consumer)
set -euo pipefail
build_dir=$(cd "$1" && pwd)
shift
here=$(cd "$(dirname "$0")" && pwd)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cmake --install "$build_dir" --prefix "$work/prefix" >/dev/null
generator=()
command -v ninja >/dev/null && generator=(-G Ninja)
cmake -S "$here/consumer" -B "$work/build" "${generator[@]}" -DCMAKE_PREFIX_PATH="$work/prefix" \
  -DCMAKE_BUILD_TYPE=Release "$@" >/dev/null
cmake --build "$work/build" >/dev/null
"$work/build/pbve_consumer"
