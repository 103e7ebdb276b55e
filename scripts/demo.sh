#!/usr/bin/env bash
# The main job, from a fresh clone: installs what is missing, builds (Release), then runs
# vibid-sim as a virtual shaker controller on loopback (Modbus TCP) and vibidd against it,
# printing the converging estimates against the truth and leaving tracks CSV + PNG plot in
# out/demo/. Build tree: build/release (override the root with VIBID_BUILD_ROOT).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
root=${VIBID_BUILD_ROOT:-build}
cmake -S . -B "$root/release" -G Ninja -DCMAKE_BUILD_TYPE=Release -DVIBID_BUILD_TESTS=OFF >/dev/null
cmake --build "$root/release" -j "$(nproc)"
echo
examples/demo/loopback_demo.sh "$root/release" out/demo "${VIBID_DEMO_SECONDS:-20}"
