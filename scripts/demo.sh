#!/usr/bin/env bash
# The main job, from a fresh clone: installs what is missing, builds (Release) and
# runs the identification demos, printing estimated against true parameters.
# Build tree: build/release (override the root with VIBID_BUILD_ROOT).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
root=${VIBID_BUILD_ROOT:-build}
cmake -S . -B "$root/release" -G Ninja -DCMAKE_BUILD_TYPE=Release -DVIBID_BUILD_TESTS=OFF >/dev/null
cmake --build "$root/release" -j "$(nproc)"
echo
"$root/release/examples/demo/vibid-demo"
