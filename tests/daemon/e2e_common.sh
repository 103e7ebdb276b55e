# e2e_common.sh: the prologue of the vibidd end-to-end scripts (e2e.sh, e2e_auto.sh,
# e2e_ekf.sh), sourced with their arguments CASE BUILD_DIR SOURCE_DIR and a name for the
# scratch directory. Sets CASE, BUILD, SRC, VIBIDD, SIM and W (a fresh directory, removed
# on exit, made the working directory) and defines fail, note, column, free_port,
# status_val, wait_status, start_sim_modbus, find_thread, thread_sched, wait_log, start_peer,
# term_and_wait and make_ca.
# usage: . e2e_common.sh NAME CASE BUILD_DIR SOURCE_DIR
set -u
CASE=$2
BUILD=$3
SRC=$4
VIBIDD=$BUILD/daemon/vibidd
SIM=$BUILD/sim/vibid-sim
W=$(mktemp -d "/tmp/vd_$1_${CASE}_XXXXXX")
trap '[ -n "${KEEP:-}" ] || rm -rf "$W"' EXIT
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

# start_sim_modbus ARGS...: vibid-sim (its arguments ARGS, which name the stand) serving Modbus
# TCP on a free port of 127.0.0.1; returns once it listens. Sets SIMPID and PORT.
start_sim_modbus() {
    [ -x "$SIM" ] || fail "vibid-sim not built ($SIM)"
    "$SIM" "$@" --modbus 127.0.0.1:0 > sim.out 2> sim.err &
    SIMPID=$!
    PORT=
    for _ in $(seq 50); do
        PORT=$(sed -n 's/.*listening on 127.0.0.1:\([0-9]*\).*/\1/p' sim.out)
        [ -n "$PORT" ] && break
        sleep 0.1
    done
    [ -n "$PORT" ] || fail "vibid-sim did not start: $(cat sim.err)"
}

# find_thread TPID NAME: vibidd's thread NAME, vibidd being the child of TPID (a timeout
# command started with &) or TPID itself; waits up to 5 s for it. Sets PID (vibidd's) and TID.
find_thread() {
    PID= TID=
    for _ in $(seq 50); do
        [ -n "$PID" ] || PID=$(cat "/proc/$1/task/$1/children" 2> /dev/null | awk '{ print $1 }')
        [ -n "$PID" ] && TID=$(grep -lx "$2" /proc/"$PID"/task/*/comm 2> /dev/null | head -1 | cut -d/ -f5)
        [ -n "$TID" ] && return 0
        sleep 0.1
    done
    fail "no thread named $2 in vibidd ($(cat /proc/"$PID"/task/*/comm 2> /dev/null | tr '\n' ' '))"
}

# thread_sched TID: "POLICY NICE" of vibidd's thread TID (PID as find_thread set it): the stat
# fields after the ")" that ends the name, 41 policy (5 = SCHED_IDLE) and 19 nice (proc(5))
thread_sched() { sed 's/.*) //' "/proc/$PID/task/$1/stat" | awk '{ print $(41 - 2), $(19 - 2) }'; }

# wait_log FILE PATTERN SECONDS: until FILE has a line matching PATTERN (grep -E); 1 if not
wait_log() {
    for _ in $(seq $(($3 * 10))); do
        grep -Eq "$2" "$1" 2> /dev/null && return 0
        sleep 0.1
    done
    return 1
}

# start_peer LOG MODE PORT ARGS...: a small hostile peer of tests/daemon/tools/hostile_peer.py
# (MODE silent, proxy or http) on 127.0.0.1:PORT, writing what it sees to LOG; returns once it
# listens. Sets PEERPID and adds it to PIDS (the caller's cleanup kills them).
start_peer() {
    local logf=$1 mode=$2 port=$3
    shift 3
    python3 "$SRC/tests/daemon/tools/hostile_peer.py" "$mode" "$port" "$logf" "$@" > "$logf.out" 2>&1 &
    PEERPID=$!
    PIDS+=("$PEERPID")
    for _ in $(seq 50); do
        grep -q '^listening on' "$logf.out" 2> /dev/null && return 0
        kill -0 $PEERPID 2> /dev/null || fail "hostile_peer.py $mode exited: $(cat "$logf.out")"
        sleep 0.1
    done
    fail "hostile_peer.py $mode did not listen on $port"
}

# term_and_wait PID SECONDS: SIGTERM to PID (a child of this shell) and wait for its end, at
# most SECONDS: a liveness bound, which the caller states, never a speed figure (fails when it
# still runs). Sets RC (its exit status) and DT (ms from the signal to its end).
term_and_wait() {
    local t0
    t0=$(date +%s%N)
    kill -TERM "$1"
    for _ in $(seq $(($2 * 10))); do
        kill -0 "$1" 2> /dev/null || break
        sleep 0.1
    done
    kill -0 "$1" 2> /dev/null && fail "SIGTERM: still running after $2 s"
    wait "$1"
    RC=$?
    DT=$((($(date +%s%N) - t0) / 1000000))
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
