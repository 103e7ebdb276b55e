#!/usr/bin/env bash
# Builds the Python package (python/) into the test venv and runs its tests (python/tests).
#
# Usage: scripts/python-test.sh [LIB_BUILD_DIR]
#   LIB_BUILD_DIR  a build tree of the top-level CMake with libvibid.a and libvibid_stand.a
#                  built (scripts/test.sh passes build/werror): the package links those
#                  instead of compiling lib/ a second time, which would add minutes to CI.
#                  Without it the package compiles lib/ itself, exactly as
#                  `python -m pip install ./python` does for a user.
# The build tree is ${VIBID_BUILD_ROOT:-build}/python and is kept between runs, so a second
# run only relinks what changed. The build backend comes from the venv (pinned in
# scripts/python-venv.sh), not from an isolated download per run.
set -euo pipefail
cd "$(dirname "$0")/.."

root=${VIBID_BUILD_ROOT:-build}
py=$(VIBID_BUILD_ROOT="$root" scripts/python-venv.sh --print | tail -n 1)
mkdir -p "$root/python"
args=(--no-build-isolation --disable-pip-version-check --quiet --force-reinstall --no-deps
      -C "build-dir=$(cd "$root/python" && pwd)")
if [[ -n "${1:-}" ]]; then
  args+=(-C "cmake.define.VIBID_LIB_BUILD_DIR=$(cd "$1" && pwd)")
fi
echo "python-test: building the package into $py"
"$py" -m pip install "${args[@]}" ./python
# From the repository root, so that `import vibid` is the installed package (the source
# tree python/vibid has no compiled _core).
VIBID_BUILD_ROOT="$root" "$py" -m pytest -q python/tests
