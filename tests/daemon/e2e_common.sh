# e2e_common.sh: the prologue of the vibidd end-to-end scripts (e2e.sh, e2e_auto.sh,
# e2e_ekf.sh), sourced with their arguments CASE BUILD_DIR SOURCE_DIR and a name for the
# scratch directory. Sets CASE, BUILD, SRC, VIBIDD, SIM and W (a fresh directory, removed
# on exit, made the working directory) and defines fail, note, column, free_port,
# status_val, wait_status and make_ca.
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

# free_port: a TCP port on 127.0.0.1 that is free now (for a server the test starts)
free_port() { python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }

# status_val KEY [FILE]: KEY's value in a status file (default ./status); "" if absent
status_val() { sed -n "s/^$1=//p" "${2:-status}" 2> /dev/null; }

# wait_status KEY AWK_CONDITION SECONDS: until ./status's KEY satisfies the condition on v
# (e.g. 'v >= 3'); 1 if it did not within SECONDS (default 5)
wait_status() {
    for _ in $(seq $((${3:-5} * 10))); do
        v=$(status_val "$1")
        [ -n "$v" ] && awk -v v="$v" "BEGIN { exit !($2) }" && return 0
        sleep 0.1
    done
    return 1
}

# make_ca: in the working directory, two self-signed CAs (ca.pem/ca.key, other.pem/other.key)
# and a server certificate for 127.0.0.1 signed by ca (server.pem/server.key), with openssl
make_ca() {
    for ca in ca other; do
        openssl req -x509 -newkey rsa:2048 -nodes -keyout $ca.key -out $ca.pem -days 2 -subj "/CN=vibid test $ca" 2> /dev/null ||
            fail "openssl: CA"
    done
    openssl req -newkey rsa:2048 -nodes -keyout server.key -out server.csr -subj "/CN=127.0.0.1" 2> /dev/null || fail "openssl: csr"
    printf 'subjectAltName=IP:127.0.0.1\n' > san.ext
    openssl x509 -req -in server.csr -CA ca.pem -CAkey ca.key -CAcreateserial -out server.pem -days 2 -extfile san.ext 2> /dev/null ||
        fail "openssl: server certificate"
}
