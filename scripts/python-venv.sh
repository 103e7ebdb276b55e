#!/usr/bin/env bash
# Creates (or checks) the Python virtual environment that the drivers' tests use for
# independent reference implementations: cantools (DBC decoding), pymodbus (a Modbus
# TCP server nobody here wrote) and python-can (its candump-format logger); and that the
# Python package's tests run in (scripts/python-test.sh): numpy, pandas and pytest, the
# package's optional capture readers (asammdf for ASAM MDF4, npTDMS for NI TDMS: the
# extras mdf and tdms, whose tests write their files with these libraries), and the
# package's build backend (scikit-build-core, nanobind), installed here so that the package
# builds without build isolation, i.e. without fetching them again on every run.
# matplotlib: the extra plot (Result.plot() and the `vibid identify --report` figures),
# whose tests draw with it headless (Agg).
# dask and distributed: vibid.identify_many's Dask path (the extra dask), tested on a
# LocalCluster.
# scipy: tests and benchmarks only, the yardstick of the output-error fit (issue 29): what a
# careful analyst writes, scipy.optimize.least_squares on the same physical model; the
# package itself does not use it.
#
# Usage: scripts/python-venv.sh            -> venv at ${VIBID_BUILD_ROOT:-build}/venv
#        scripts/python-venv.sh --print    -> also print the venv's python path (last line)
# Idempotent: when the venv exists and holds exactly the pinned versions it only checks
# them (well under a second) and installs nothing. Versions are pinned so that test
# results do not change under our feet when upstream releases.
# The tests find the interpreter through the CMake cache variable VIBID_PYTHON or the
# environment variable VIBID_PYTHON (e.g. VIBID_PYTHON=build/venv/bin/python).
set -euo pipefail
cd "$(dirname "$0")/.."

root=${VIBID_BUILD_ROOT:-build}
venv="$root/venv"
pins=(cantools==40.7.1 pymodbus==3.6.9 pyserial==3.5 python-can==4.6.1
      numpy==2.4.6 pandas==3.1.1 pytest==9.2.0 nanobind==3.1.0 scikit-build-core==1.1.2
      asammdf==8.8.28 npTDMS==1.13.0
      matplotlib==3.11.2
      dask==2026.8.0 distributed==2026.8.0
      scipy==1.17.1)
stamp="$venv/.vibid-pins"
want="${pins[*]}"

if [[ -x "$venv/bin/python" && -f "$stamp" && "$(cat "$stamp")" == "$want" ]]; then
  if "$venv/bin/python" -c 'import cantools, pymodbus, can, numpy, pandas, pytest, nanobind, scikit_build_core, asammdf, nptdms, matplotlib, dask, distributed, scipy' 2>/dev/null; then
    echo "python-venv: $venv ready (${pins[*]})"
    [[ "${1:-}" == "--print" ]] && echo "$(cd "$venv" && pwd)/bin/python"
    exit 0
  fi
fi

py=${PYTHON:-python3}
if ! "$py" -c 'import venv, ensurepip' 2>/dev/null; then
  echo "python-venv: $py lacks the venv/ensurepip modules (Debian: apt-get install python3-venv)" >&2
  exit 1
fi
echo "python-venv: creating $venv with ${pins[*]}"
mkdir -p "$root"
"$py" -m venv "$venv"
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check "${pins[@]}"
"$venv/bin/python" -c 'import cantools, pymodbus, can, numpy, pandas, pytest, nanobind, scikit_build_core, asammdf, nptdms, matplotlib, dask, distributed, scipy'
echo "$want" > "$stamp"
echo "python-venv: $venv ready"
[[ "${1:-}" == "--print" ]] && echo "$(cd "$venv" && pwd)/bin/python"
exit 0
