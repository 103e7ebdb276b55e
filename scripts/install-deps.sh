#!/usr/bin/env bash
# Installs the Debian (bookworm) packages vibid needs, only those missing.
# Usage: scripts/install-deps.sh [--test]   (--test adds what only the tests need)
# Needs root (or sudo) when something is missing; does nothing when all is there.
set -euo pipefail

# Build: compilers, CMake, and the libraries of every part.
packages=(build-essential cmake ninja-build pkg-config libeigen3-dev libcmocka-dev
          libsundials-dev libmodbus-dev libconfig-dev)
# vibidd's MQTT output (outputs.mqtt, daemon/src/mqtt.c)
packages+=(libmosquitto-dev)
# vibidd's InfluxDB HTTP output (outputs.influx.http, daemon/src/influx_http.c)
packages+=(libcurl4-openssl-dev)
# Demo plots.
packages+=(gnuplot-nox)
if [[ "${1:-}" == "--test" ]]; then
  # Independent peers and tools for tests: can-utils (candump/cangen/canplayer),
  # qemu + busybox + cpio for the SocketCAN VM test, python3-venv for cantools/pymodbus,
  # clang + its runtime for the libFuzzer targets of the parsers, python3-dev for the
  # headers the Python package's extension module compiles against (python/).
  packages+=(can-utils qemu-system-x86 busybox-static cpio xz-utils python3-venv python3-dev clang
             libclang-rt-14-dev)
  packages+=(systemd)  # systemd-analyze, and systemd as PID 1 in the VM (tests/daemon/systemd)
  # promtool (`promtool check metrics`) and a real Prometheus server scraping vibidd's
  # metrics endpoint (daemon.e2e.prometheus, daemon.e2e.prometheus_server)
  packages+=(prometheus)
  # a real MQTT broker (mosquitto, with mosquitto_passwd) and its clients (mosquitto_sub,
  # mosquitto_pub) for vibidd's MQTT tests (daemon.e2e_mqtt.*); openssl makes their CA
  packages+=(mosquitto mosquitto-clients openssl)
  # a real InfluxDB server (1.6) for vibidd's InfluxDB HTTP tests (daemon.e2e_influx.*);
  # curl reads what they wrote back through its query API
  packages+=(influxdb curl)
  packages+=(chromium)  # headless screenshots of vibid identify --report (python/tests/test_report.py)
fi

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done
if (( ${#missing[@]} == 0 )); then
  echo "install-deps: all ${#packages[@]} packages present"
  exit 0
fi

echo "install-deps: installing ${missing[*]}"
SUDO=""
if [[ $(id -u) -ne 0 ]]; then
  if command -v sudo >/dev/null; then SUDO=sudo; else
    echo "install-deps: not root and no sudo; please install: ${missing[*]}" >&2
    exit 1
  fi
fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
