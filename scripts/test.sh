#!/usr/bin/env bash
# The whole test suite, from a fresh clone: installs what is missing, builds with
# -Wall -Wextra -Werror and runs every test through ctest, then builds again with
# AddressSanitizer + UndefinedBehaviorSanitizer and runs the same tests.
# Build trees: build/werror and build/sanitize (override with VIBID_BUILD_ROOT).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh --test

root=${VIBID_BUILD_ROOT:-build}
jobs=$(nproc)
# Independent reference tools from PyPI (cantools, pymodbus, python-can) for the tests, and
# what the Python package needs to build and test (numpy, pandas, pytest, nanobind,
# scikit-build-core).
VIBID_BUILD_ROOT="$root" scripts/python-venv.sh

# Everything the tests need is installed above, so a test that skips (exit 77 under ctest,
# pytest.skip) is a missing install: VIBID_NO_SKIP=1 makes pytest fail on a skip, and
# run_suite fails when ctest reports one (ctest itself exits 0 with skipped tests).
export VIBID_NO_SKIP=1

run_suite() {
  local name=$1; shift
  echo "==== test suite: $name ===="
  cmake -S . -B "$root/$name" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DVIBID_WERROR=ON "$@"
  cmake --build "$root/$name" -j "$jobs"
  ctest --test-dir "$root/$name" --output-on-failure -j "$jobs" --timeout 900 \
    | tee "$root/$name/ctest.out"
  if grep -q '\*\*\*Skipped' "$root/$name/ctest.out"; then
    echo "test suite $name: skipped tests (a missing install; VIBID_NO_SKIP=1):"
    grep '\*\*\*Skipped' "$root/$name/ctest.out"
    exit 1
  fi
}

run_suite werror
# The Python package, linked against the libraries just built, and its pytest suite (not
# under the sanitizers: an ASan runtime would have to be preloaded into the interpreter).
echo "==== test suite: python ===="
VIBID_BUILD_ROOT="$root" scripts/python-test.sh "$root/werror"
# Sanitized build: -O1 keeps it fast enough; leaks are errors too. The libFuzzer targets
# ran in the first suite with their own ASan + UBSan build; they are not built again.
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  run_suite sanitize -DVIBID_SANITIZE=ON -DCMAKE_BUILD_TYPE=Debug -DCMAKE_CXX_FLAGS=-O1 -DCMAKE_C_FLAGS=-O1 -DVIBID_BUILD_BENCH=OFF -DVIBID_FUZZ=OFF
echo "==== all test suites passed ===="
