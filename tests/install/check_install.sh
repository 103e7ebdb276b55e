#!/usr/bin/env bash
# check_install.sh BUILD_DIR SCRATCH_DIR CONSUMER_SRC
# Installs BUILD_DIR into SCRATCH_DIR/prefix and builds/runs the consumers there.
set -euo pipefail
build=$1 scratch=$2 src=$3
rm -rf "$scratch"
mkdir -p "$scratch"
prefix="$scratch/prefix"
cmake --install "$build" --prefix "$prefix" >/dev/null
libdir=$(find "$prefix" -name libvibid.so -printf '%h\n' | head -n1)
[[ -n "$libdir" && -f "$libdir/libvibid.a" && -f "$libdir/pkgconfig/vibid.pc" ]] || {
  echo "install incomplete under $prefix"; find "$prefix"; exit 1; }

echo "--- CMake consumer (find_package(vibid))"
cmake -S "$src" -B "$scratch/cmake-build" -DCMAKE_PREFIX_PATH="$prefix" >/dev/null
cmake --build "$scratch/cmake-build" >/dev/null
LD_LIBRARY_PATH="$libdir" "$scratch/cmake-build/consumer_shared"
"$scratch/cmake-build/consumer_static"

echo "--- Makefile consumer (pkg-config)"
PKG_CONFIG_PATH="$libdir/pkgconfig" make -s -C "$src" -f Makefile.pkgconfig OUT="$scratch/make"
LD_LIBRARY_PATH="$libdir" "$scratch/make/consumer_shared"
"$scratch/make/consumer_static"
echo "install check passed"
