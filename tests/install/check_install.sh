#!/usr/bin/env bash
# Installs the build tree BUILD_DIR into a temporary prefix, runs the installed pbve command
# (when installed), then configures, builds and runs a separate consumer project that finds pbve
# with find_package(pbve REQUIRED): a program, and the example adapter's conformance test. Then
# builds and runs the same program without CMake, with the flags of the installed pbve.pc
# (pkg-config; --static for static libraries), and compiles a header that includes OpenCV's
# with -Wall -Wextra -Werror and those flags.
# Usage: check_install.sh BUILD_DIR [CMAKE_ARG...]   (extra arguments configure the consumer;
# its CMAKE_CXX_COMPILER, CMAKE_CXX_FLAGS and CMAKE_EXE_LINKER_FLAGS also build the second one)
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

cxx=c++ cxxflags="" ldflags=""
for a in "$@"; do
  case $a in
    -DCMAKE_CXX_COMPILER=*) cxx=${a#*=} ;;
    -DCMAKE_CXX_FLAGS=*) cxxflags=${a#*=} ;;
    -DCMAKE_EXE_LINKER_FLAGS=*) ldflags=${a#*=} ;;
  esac
done
pc=$(find "$work/prefix" -name pbve.pc -print -quit)
if [ -z "$pc" ]; then
  echo "check_install: no pbve.pc under the prefix" >&2
  exit 1
fi
static=()
[ -n "$(find "$work/prefix" -name libpbve_core.a -print -quit)" ] && static=(--static)
export PKG_CONFIG_PATH
PKG_CONFIG_PATH=$(dirname "$pc")${PKG_CONFIG_PATH:+:$PKG_CONFIG_PATH}
pkg-config --print-errors --exists pbve
libdir=$(pkg-config --variable=libdir pbve)
flags=$(pkg-config "${static[@]}" --cflags --libs pbve)
read -ra pc_flags <<<"$flags"
read -ra extra <<<"$cxxflags $ldflags"
"$cxx" -std=c++20 "${extra[@]}" "$here/consumer/main.cpp" -o "$work/pc_consumer" \
  "${pc_flags[@]}" -Wl,-rpath,"$libdir"
"$work/pc_consumer"
# A header that includes OpenCV's compiles without a warning: the dependencies' folders come as
# system headers, as with CMake.
printf '#include <pbve/core/footage.hpp>\nint main() { return 0; }\n' >"$work/headers.cpp"
"$cxx" -std=c++20 -Wall -Wextra -Werror "${extra[@]}" -c "$work/headers.cpp" -o "$work/headers.o" \
  "${pc_flags[@]}"
