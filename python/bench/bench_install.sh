#!/usr/bin/env bash
# bench_install.sh: how long a user's `pip install ./python` takes from a clean state, beside
# a yardstick measured in the same run: compiling libvibid alone (cmake + ninja, the
# shared library only, the same compiler and flags the package's build uses for lib/).
# The install builds lib/, the drivers, vibidd's core and the nanobind module, so its
# ratio to the yardstick is the figure that holds across machines; the seconds do not.
#
# Usage: python/bench/bench_install.sh [PYTHON]   (default python3; needs network access to
# the package index for the build backend and numpy/pandas, as a user's install does)
# Prints one line per step and the ratio. Work happens in a temporary directory, removed
# at the end; the repository is not written to.
set -euo pipefail
cd "$(dirname "$0")/../.."
py=${1:-python3}
work=$(mktemp -d /tmp/vibid_bench_install.XXXXXX)
trap 'rm -rf "$work"' EXIT
jobs=$(nproc)

now() { date +%s.%N; }
secs() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%.1f", b - a }'; }

# Yardstick: libvibid alone, Release as the package builds it (scikit-build-core's default).
t0=$(now)
cmake -S . -B "$work/lib" -G Ninja -DCMAKE_BUILD_TYPE=Release -DVIBID_BUILD_TESTS=OFF \
      -DVIBID_BUILD_BENCH=OFF > "$work/lib.log" 2>&1
cmake --build "$work/lib" -j "$jobs" --target vibid_shared >> "$work/lib.log" 2>&1
t1=$(now)
lib_s=$(secs "$t0" "$t1")
echo "yardstick: libvibid alone (cmake + ninja -j$jobs, vibid_shared): $lib_s s"

# The user's install: a fresh venv, pip's own build isolation (the backend downloaded), a
# fresh pip cache so that no wheel of an earlier run is reused.
"$py" -m venv "$work/venv" > /dev/null
"$work/venv/bin/python" -m pip install --quiet --upgrade pip > /dev/null 2>&1 || true
t2=$(now)
PIP_CACHE_DIR="$work/pipcache" "$work/venv/bin/python" -m pip install --quiet ./python > "$work/pip.log" 2>&1 ||
    { tail -20 "$work/pip.log"; echo "bench_install: pip install failed"; exit 1; }
t3=$(now)
pip_s=$(secs "$t2" "$t3")
"$work/venv/bin/python" -c 'import vibid, vibid._core as c; assert c.HAVE_DRIVERS and c.HAVE_DAEMON' ||
    { echo "bench_install: the installed package lacks the drivers or vibidd's core"; exit 1; }
sim=$("$work/venv/bin/python" -c 'from vibid import _cli; print(_cli.PACKAGED_SIM)')
"$sim" --version > /dev/null || { echo "bench_install: the package's vibid-sim ($sim) does not run"; exit 1; }
echo "pip install ./python (fresh venv and cache; drivers, vibidd's core and vibid-sim included): $pip_s s"
awk -v a="$pip_s" -v b="$lib_s" 'BEGIN { printf "ratio install / yardstick: %.2f\n", a / b }'
