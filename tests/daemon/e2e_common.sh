# e2e_common.sh: the prologue of the vibidd end-to-end scripts (e2e.sh, e2e_auto.sh,
# e2e_ekf.sh), sourced with their arguments CASE BUILD_DIR SOURCE_DIR and a name for the
# scratch directory. Sets CASE, BUILD, SRC, VIBIDD, SIM and W (a fresh directory, removed
# on exit, made the working directory) and defines fail, note and column.
# usage: . e2e_common.sh NAME CASE BUILD_DIR SOURCE_DIR
set -u
CASE=$2
BUILD=$3
SRC=$4
VIBIDD=$BUILD/daemon/vibidd
SIM=$BUILD/sim/vibid-sim
W=$(mktemp -d "/tmp/vd_$1_${CASE}_XXXXXX")
trap 'rm -rf "$W"' EXIT
cd "$W" || exit 1

fail() { echo "FAIL [$CASE]: $*" >&2; exit 1; }
note() { echo "[$CASE] $*"; }

# column NAME FILE: the column number of NAME in the tracks header (after the # lines)
column() { grep -v '^#' "$2" | head -1 | tr ',' '\n' | grep -nx "$1" | cut -d: -f1; }
