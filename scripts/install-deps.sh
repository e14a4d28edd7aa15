#!/usr/bin/env bash
# Installs the Debian packages pbve builds and runs with. Quick when they are present.
# Usage: scripts/install-deps.sh [fuzz]   (needs root, or sudo)
#   fuzz: also clang++ with libFuzzer and the sanitizer runtimes, and llvm-symbolizer
#         (the `fuzz` preset, scripts/run-fuzz.sh)
set -euo pipefail

packages=(
  build-essential cmake ninja-build pkg-config git
  libeigen3-dev libnlopt-cxx-dev libnlopt-dev libopencv-dev libembree-dev libtbb-dev
  coinor-libipopt-dev libbullet-dev libyaml-cpp-dev
  libsuitesparse-dev libopenblas-dev
  nlohmann-json3-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  ffmpeg
)
for group in "$@"; do
  case "$group" in
    fuzz) packages+=(clang libclang-rt-14-dev llvm) ;;
    *)
      echo "install-deps: unknown group '$group' (known: fuzz)" >&2
      exit 2
      ;;
  esac
done

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#packages[@]} packages present"
  exit 0
fi

sudo_cmd=()
if [ "$(id -u)" -ne 0 ]; then sudo_cmd=(sudo); fi
echo "install-deps: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
"${sudo_cmd[@]}" apt-get update -qq
"${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}"
