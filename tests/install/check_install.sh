#!/usr/bin/env bash
# Installs the build tree BUILD_DIR into a temporary prefix, runs the installed pbve command
# (when installed), then configures, builds and runs a separate consumer project that finds pbve
# with find_package(pbve REQUIRED): a program, and the example adapter's conformance test.
# Usage: check_install.sh BUILD_DIR [CMAKE_ARG...]   (extra arguments configure the consumer)
set -euo pipefail
build_dir=$(cd "$1" && pwd)
shift
here=$(cd "$(dirname "$0")" && pwd)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cmake --install "$build_dir" --prefix "$work/prefix" >/dev/null
# The installed command finds its libraries by itself (install RPATH).
if [ -x "$work/prefix/bin/pbve" ]; then
  env -u LD_LIBRARY_PATH "$work/prefix/bin/pbve" --help >/dev/null
fi
generator=()
command -v ninja >/dev/null && generator=(-G Ninja)
cmake -S "$here/consumer" -B "$work/build" "${generator[@]}" -DCMAKE_PREFIX_PATH="$work/prefix" \
  -DCMAKE_BUILD_TYPE=Release -DPBVE_EXAMPLE_ADAPTER_DIR="$here/../../examples/custom_adapter" \
  "$@" >/dev/null
cmake --build "$work/build" >/dev/null
"$work/build/pbve_consumer"
"$work/build/adapter_conformance" --gtest_brief=1
