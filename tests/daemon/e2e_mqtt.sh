#!/usr/bin/env bash
# End-to-end tests of vibidd's MQTT output (outputs.mqtt, daemon/src/mqtt.h) against a real
# broker: Debian's mosquitto, started by each case on a free loopback port with a
# configuration, password file, ACL and (tls) a CA and server certificate of its own, made
# here with mosquitto_passwd and openssl. Subscribers are mosquitto_sub (-v -q 1) writing to
# a file; payloads are checked with the system's python3 (json).
# usage: e2e_mqtt.sh CASE BUILD_DIR SOURCE_DIR
#   publish  a paced replay: every track row arrives, seq 1..N without a gap, values equal to
#            the tracks CSV row for row; the retained status says "stopped" after the end
#   auth     a wrong password: refused, logged, retried, counted; SIGTERM exits 0; then the
#            right password publishes
#   acl      an ACL that denies the tracks topic: MQTT 5 shows the refusals (mqtt_refused and a
#            warning), MQTT 3.1.1 cannot (the broker acknowledges and drops)
#   tls      mqtts with the test's CA works; with another CA: certificate verify failed,
#            retried, exit 0
#   restart  the broker killed (kill -9) and restarted mid-run: every seq arrives (at least
#            once: duplicates allowed and counted)
#   drops    a queue of 5 and a 5 s outage: drops counted in the status, the message after a
#            gap carries dropped_before = the gap
#   will     vibidd killed (kill -9): the retained status turns "offline" (the last will);
#            on the way, its Prometheus endpoint shows the vibid_mqtt_* families (promtool)
#   drain_reconnect  a replay that ends while vibidd cannot reach the broker (nothing listens
#            on its port; a proxy to the broker opens there once the replay has ended): the
#            drain waits for the reconnection, every row arrives, the retained status is
#            "stopped" (issue 30 item 5: 200 of 200 rows were lost in 0.085 s)
#   flaps    every connection cut 200 ms after it was made (a proxy of tools/hostile_peer.py):
#            every row arrives (duplicates allowed), the retained status ends "stopped",
#            not the will's "offline", nothing is counted unsent
#   silent   a peer that accepts the connection and never answers CONNECT: a clear warning
#            after 5 s (not "Unknown error." after 30 s), counted; SIGTERM does not wait
#            drain_timeout (60 s) for it, and what was not sent is counted (mqtt_unsent)
. "$(dirname "$0")/e2e_common.sh" e2e_mqtt "$@"
GEN=$BUILD/tests/daemon/vd_gen_capture
STAND=$SRC/examples/stands/paper_example1.cfg
TOPIC=vibid/v1/p1/paper_example1

if ! command -v mosquitto > /dev/null && [ ! -x /usr/sbin/mosquitto ]; then
    echo "SKIPPED [$CASE]: the mosquitto broker is not installed (Debian packages mosquitto and"
    echo "SKIPPED [$CASE]: mosquitto-clients, scripts/install-deps.sh --test); the MQTT test was NOT run"
    exit 77
fi
MOSQUITTO=$(command -v mosquitto || echo /usr/sbin/mosquitto)
command -v mosquitto_sub > /dev/null || fail "mosquitto_sub not found (Debian package mosquitto-clients)"

PIDS=()
cleanup() {
    exec 2> /dev/null # (bash's job notices of the peers killed here)
    for p in "${PIDS[@]}"; do kill -9 "$p" 2> /dev/null; done
    wait 2> /dev/null
    rm -rf "$W"
}
trap cleanup EXIT

# broker_conf FILE PORT [EXTRA...]: a broker on 127.0.0.1:PORT (root keeps its user: the test's
# files are root's)
broker_conf() {
    local f=$1 port=$2
    shift 2
    {
        echo "listener $port 127.0.0.1"
        [ "$(id -u)" = 0 ] && echo "user root"
        echo "log_dest file $W/broker.log"
        echo "log_type all"
        printf '%s\n' "$@"
    } > "$f"
}

# start_broker CONF PORT: sets BPID; waits until the port accepts connections
start_broker() {
    "$MOSQUITTO" -c "$1" >> broker.out 2>&1 &
    BPID=$!
    PIDS+=("$BPID")
    for _ in $(seq 50); do
        python3 -c "import socket, sys; socket.create_connection(('127.0.0.1', $2), timeout=0.2)" 2> /dev/null && return 0
        kill -0 $BPID 2> /dev/null || fail "mosquitto exited: $(cat broker.out; tail -5 broker.log 2> /dev/null)"
        sleep 0.1
    done
    fail "mosquitto did not listen on $2: $(cat broker.out)"
}

# start_sub OUT "SUB_ONLY_ARGS" ARGS...: mosquitto_sub -v -q 1 on vibid/# into OUT
# (line-buffered); returns once it receives a probe message that mosquitto_pub sends with
# ARGS (so it is subscribed); sets SUBPID
start_sub() {
    local outf=$1 only=$2
    shift 2
    # shellcheck disable=SC2086
    stdbuf -oL mosquitto_sub -h 127.0.0.1 -v -q 1 -t 'vibid/#' $only "$@" > "$outf" 2> "$outf.err" &
    SUBPID=$!
    PIDS+=("$SUBPID")
    for _ in $(seq 50); do
        mosquitto_pub -h 127.0.0.1 -q 1 -t vibid/probe -m ready "$@" 2> /dev/null
        grep -q '^vibid/probe ready' "$outf" && return 0
        sleep 0.1
    done
    fail "mosquitto_sub did not subscribe: $(cat "$outf.err")"
}

# config FILE MQTT_GROUP_BODY [EXTRA]: a paced replay of cap.csv with outputs.mqtt
config() {
    cat > "$1" << EOF
stand = "$STAND";
source = {
  kind = "replay"; file = "cap.csv"; time_column = "t"; paced = true;
  channels = (
    { name = "x1"; quantity = "displacement"; node = 0; unit = "m"; column = "x1"; },
    { name = "x2"; quantity = "displacement"; node = 1; unit = "m"; column = "x2"; },
    { name = "s";  quantity = "base_displacement"; node = 0; unit = "m"; column = "s"; }
  );
};
estimator = { method = "rls"; prefilter_hz = 200.0; decimation = 200; };
outputs = { tracks = { path = "tracks.csv"; }; status = { path = "status"; interval = 0.2; };
            mqtt = { site = "p1"; $2 }; };
${3:-}
EOF
}


# check_tracks SUB_OUT TRACKS_CSV [dups]: the tracks messages against the CSV: every seq
# 1..N (N = CSV rows; duplicates only with "dups"), each seq's payload equal to its row
check_tracks() {
    python3 - "$1" "$2" "${3:-}" "$TOPIC" << 'PYEOF'
import csv, json, math, sys
sub, tracks, dups, topic = sys.argv[1], sys.argv[2], sys.argv[3] == "dups", sys.argv[4]
msgs = []
for line in open(sub):
    t, _, p = line.rstrip("\n").partition(" ")
    if t == topic + "/tracks":
        msgs.append(json.loads(p))
rows = list(csv.DictReader(l for l in open(tracks) if not l.startswith("#")))
seqs = [m["seq"] for m in msgs]
if not dups and seqs != list(range(1, len(rows) + 1)):
    missing = sorted(set(range(1, len(rows) + 1)) - set(seqs))
    sys.exit(f"seq: {len(seqs)} messages for {len(rows)} rows; missing {missing[:20]}; first {seqs[:10]}")
if dups and sorted(set(seqs)) != list(range(1, len(rows) + 1)):
    missing = sorted(set(range(1, len(rows) + 1)) - set(seqs))
    sys.exit(f"seq: {len(set(seqs))} distinct of {len(rows)} rows; missing {missing[:20]}")
def num(s):
    return None if s == "nan" else float(s)
by_seq = {}
for m in msgs:
    if m["seq"] in by_seq and by_seq[m["seq"]] != m:
        sys.exit(f"seq {m['seq']} twice with different payloads")
    by_seq[m["seq"]] = m
for i, r in enumerate(rows, 1):
    m = by_seq[i]
    assert m["stand"] == "paper_example1" and m["site"] == "p1", m
    assert m["index"] == int(r["index"]), (i, m["index"], r["index"])
    assert m["time_s"] == float(r["time_s"]), (i, m["time_s"], r["time_s"])
    for p in ("c1", "d", "c2"):
        assert m["params"][p]["value"] == num(r[p]), (i, p, m["params"][p], r[p])
        assert m["params"][p]["se"] == num(r[p + "_se"]), (i, p, m["params"][p], r[p + "_se"])
    for k, md in enumerate(m["modes"], 1):
        for key, col in (("f_hz", f"f{k}_hz"), ("f_hz_se", f"f{k}_hz_se"), ("zeta", f"zeta{k}"), ("zeta_se", f"zeta{k}_se")):
            assert md[key] == num(r[col]), (i, key, md[key], r[col])
    assert m["flags"] == r["flags"] and m["gap_samples"] == int(r["gap_samples"]), (i, m["flags"], r["flags"])
print(f"{len(rows)} rows = {len(msgs)} messages ({len(msgs) - len(set(seqs))} duplicates), values equal")
PYEOF
}

# open_broker: an anonymous broker on a free port BPORT, a subscriber on it into sub.out, and
# PPORT, another free port (for vibidd, behind which the case puts a peer or nothing)
open_broker() {
    BPORT=$(free_port)
    broker_conf b.conf "$BPORT" "allow_anonymous true"
    start_broker b.conf "$BPORT"
    start_sub sub.out "" -p "$BPORT"
    PPORT=$(free_port)
}

# retained_status [ARGS...]: the retained status message's state ("" if none)
retained_state() {
    timeout 5 mosquitto_sub -h 127.0.0.1 -q 1 -t "$TOPIC/status" -C 1 -W 3 "$@" 2> /dev/null |
        python3 -c 'import json, sys; d = sys.stdin.read(); print(json.loads(d)["state"] if d.strip() else "")'
}

case $CASE in
publish)
    $GEN "$STAND" --duration 10 --noise 0.001 --seed 21 --csv cap.csv 2> /dev/null || fail "generator"
    PORT=$(free_port)
    broker_conf b.conf "$PORT" "allow_anonymous true"
    start_broker b.conf "$PORT"
    start_sub sub.out "" -p "$PORT"
    config v.cfg "url = \"mqtt://127.0.0.1:$PORT\";"
    timeout 10 "$VIBIDD" -c v.cfg --check > check.out 2> check.err || fail "--check: $(cat check.err)"
    grep -q "^    url = \"mqtt://127.0.0.1:$PORT\";" check.out || fail "--check printout: $(grep -A3 mqtt check.out)"
    timeout 60 "$VIBIDD" -c v.cfg --pace --speed 2 2> log; rc=$?
    [ $rc -eq 0 ] || fail "exit status $rc: $(cat log)"
    grep -q "mqtt: connected to mqtt://127.0.0.1:$PORT as 'vibidd-p1-paper_example1'" log || fail "no connect notice: $(cat log)"
    grep -q 'mqtt: every message acknowledged by the broker' log || fail "not drained: $(grep mqtt log)"
    ! grep -Eq '^vibidd: (error|warning):' log || fail "errors in the log: $(grep -E '^vibidd: (error|warning):' log)"
    sleep 0.3
    out=$(check_tracks sub.out tracks.csv) || fail "tracks: $out"
    note "$out"
    [ "$(status_val mqtt_dropped)" = 0 ] || fail "mqtt_dropped $(status_val mqtt_dropped)"
    [ "$(status_val mqtt_connect_failures)" = 0 ] || fail "connect failures"
    # the status topic: JSON of the status file's keys; the final one retained, "stopped"
    python3 - sub.out "$TOPIC" << 'PYEOF' || fail "status messages"
import json, sys
st = [json.loads(l.split(" ", 1)[1]) for l in open(sys.argv[1]) if l.startswith(sys.argv[2] + "/status ")]
assert len(st) >= 3, len(st)
assert [s["seq"] for s in st] == list(range(1, len(st) + 1)), [s["seq"] for s in st]
assert st[-1]["state"] == "stopped" and st[-2]["state"] == "running", st[-1]
for k in ("samples", "rows", "mqtt_published", "mqtt_queue_capacity", "estimate.c1"):
    assert isinstance(st[-1][k], (int, float)), (k, st[-1].get(k))
assert st[-1]["mqtt_queue_capacity"] == 10000 and st[-1]["index"] == st[-1]["last_index"]
PYEOF
    [ "$(retained_state -p "$PORT")" = stopped ] || fail "retained status: '$(retained_state -p "$PORT")'"
    note "status messages JSON with seq 1..n, the retained one 'stopped'"
    ;;
auth)
    $GEN "$STAND" --duration 10 --noise 0.001 --seed 22 --csv cap.csv 2> /dev/null || fail "generator"
    PORT=$(free_port)
    mosquitto_passwd -c -b passwd vibidd s3cret 2> /dev/null || fail "mosquitto_passwd"
    mosquitto_passwd -b passwd reader r3ad 2> /dev/null || fail "mosquitto_passwd"
    printf '%s\n' "user vibidd" "topic write vibid/v1/p1/#" "user reader" "topic read vibid/#" "topic readwrite vibid/probe" > acl
    broker_conf b.conf "$PORT" "allow_anonymous false" "password_file $W/passwd" "acl_file $W/acl"
    start_broker b.conf "$PORT"
    start_sub sub.out "" -p "$PORT" -u reader -P r3ad
    echo wrong > pw.bad
    echo s3cret > pw.good
    chmod 600 pw.bad pw.good
    config bad.cfg "url = \"mqtt://127.0.0.1:$PORT\"; username = \"vibidd\"; password_file = \"pw.bad\";"
    timeout 30 "$VIBIDD" -c bad.cfg 2> log.bad &
    pid=$!
    PIDS+=("$pid")
    wait_status mqtt_connect_failures 'v >= 3' 8 || fail "connect failures: $(status_val mqtt_connect_failures); $(cat log.bad)"
    kill -0 $pid || fail "vibidd exited on a wrong password: $(cat log.bad)"
    [ "$(status_val mqtt_connected)" = 0 ] || fail "connected with a wrong password"
    n=$(grep -c 'mqtt: cannot connect to .*: the broker refused the connection: ' log.bad)
    [ "$n" -eq 1 ] || fail "refusal logged $n times (want once per episode): $(grep mqtt log.bad)"
    grep 'the broker refused the connection' log.bad | grep -Eqi 'not authori[sz]ed|bad user' || fail "reason: $(grep mqtt log.bad)"
    kill -TERM $pid
    t0=$(date +%s%N)
    wait $pid; rc=$?
    dt=$((($(date +%s%N) - t0) / 1000000))
    [ $rc -eq 0 ] || fail "exit status $rc after SIGTERM with a wrong password: $(tail -3 log.bad)"
    [ $dt -lt 2000 ] || fail "SIGTERM took $dt ms"
    note "wrong password: $(grep -o 'the broker refused the connection: [^;]*' log.bad | head -1), $(status_val mqtt_connect_failures) failed attempts, logged once, exit 0 in $dt ms"
    rm -f tracks.csv status
    config good.cfg "url = \"mqtt://127.0.0.1:$PORT\"; username = \"vibidd\"; password_file = \"pw.good\";"
    timeout 30 "$VIBIDD" -c good.cfg --pace --speed 4 2> log.good || fail "right password: exit $? $(cat log.good)"
    sleep 0.3
    out=$(check_tracks sub.out tracks.csv) || fail "tracks with the right password: $out"
    note "right password: $out"
    ;;
acl)
    $GEN "$STAND" --duration 3 --noise 0.001 --seed 23 --csv cap.csv 2> /dev/null || fail "generator"
    PORT=$(free_port)
    mosquitto_passwd -c -b passwd vibidd s3cret 2> /dev/null || fail "mosquitto_passwd"
    # vibidd may write its status only: its tracks are refused by the broker
    printf '%s\n' "user vibidd" "topic write $TOPIC/status" > acl
    broker_conf b.conf "$PORT" "allow_anonymous false" "password_file $W/passwd" "acl_file $W/acl"
    start_broker b.conf "$PORT"
    echo s3cret > pw
    for proto in 5 3.1.1; do
        rm -f tracks.csv status
        config v.cfg "url = \"mqtt://127.0.0.1:$PORT\"; username = \"vibidd\"; password_file = \"pw\"; protocol = \"$proto\";"
        timeout 30 "$VIBIDD" -c v.cfg --pace --speed 3 2> log.$proto || fail "protocol $proto: exit $? $(cat log.$proto)"
        rows=$(($(grep -vc '^#' tracks.csv) - 1))
        ref=$(status_val mqtt_refused)
        if [ "$proto" = 5 ]; then
            [ "$ref" = "$rows" ] || fail "MQTT 5: mqtt_refused $ref for $rows rows"
            grep -q 'mqtt: the broker refused a message (mid [0-9]*): Not authorized' log.$proto || fail "no refusal warning: $(grep mqtt log.$proto)"
            note "MQTT 5: $ref of $rows track messages refused by the ACL, seen by vibidd (mqtt_refused, a warning)"
        else
            [ "$ref" = 0 ] || fail "MQTT 3.1.1: mqtt_refused $ref"
            pub=$(status_val mqtt_published)
            note "MQTT 3.1.1: the broker acknowledged $pub messages and dropped the $rows denied tracks: vibidd cannot see it (mqtt_refused 0)"
        fi
    done
    grep -q 'Denied PUBLISH' broker.log || fail "the broker logged no denial"
    ;;
tls)
    $GEN "$STAND" --duration 10 --noise 0.001 --seed 24 --csv cap.csv 2> /dev/null || fail "generator"
    PORT=$(free_port)
    make_ca
    broker_conf b.conf "$PORT" "allow_anonymous true" "cafile $W/ca.pem" "certfile $W/server.pem" "keyfile $W/server.key"
    start_broker b.conf "$PORT"
    start_sub sub.out "" -p "$PORT" --cafile ca.pem
    config v.cfg "url = \"mqtts://127.0.0.1:$PORT\"; ca_file = \"ca.pem\";"
    timeout 30 "$VIBIDD" -c v.cfg --pace --speed 3 2> log || fail "TLS: exit $? $(cat log)"
    sleep 0.3
    out=$(check_tracks sub.out tracks.csv) || fail "tracks over TLS: $out"
    note "TLS with the test's CA: $out"
    rm -f tracks.csv status
    config bad.cfg "url = \"mqtts://127.0.0.1:$PORT\"; ca_file = \"other.pem\";"
    timeout 30 "$VIBIDD" -c bad.cfg 2> log.bad &
    pid=$!
    PIDS+=("$pid")
    wait_status mqtt_connect_failures 'v >= 2' 8 || fail "connect failures with the wrong CA: $(status_val mqtt_connect_failures); $(cat log.bad)"
    grep -q 'mqtt: cannot connect to mqtts://127.0.0.1:.*certificate verify failed' log.bad || fail "no clear TLS error: $(grep mqtt log.bad)"
    kill -TERM $pid
    wait $pid || fail "exit status $? after SIGTERM with the wrong CA"
    note "wrong CA: $(grep -o 'cannot connect to [^;]*' log.bad | head -1), retried, exit 0"
    ;;
restart|drops)
    # the broker keeps the subscriber's session (persistence, a persistent client) across
    # its restart, so what vibidd publishes before the subscriber is back is kept for it
    $GEN "$STAND" --duration 16 --noise 0.001 --seed 25 --csv cap.csv 2> /dev/null || fail "generator"
    PORT=$(free_port)
    mkdir db
    broker_conf b.conf "$PORT" "allow_anonymous true" "persistence true" "persistence_location $W/db/" \
        "autosave_interval 1" "max_queued_messages 0"
    start_broker b.conf "$PORT"
    start_sub sub.out "-c -i e2e-sub" -p "$PORT"
    if [ "$CASE" = restart ]; then q=""; else q="queue_size = 5;"; fi
    config v.cfg "url = \"mqtt://127.0.0.1:$PORT\"; $q"
    sleep 1.2 # the subscriber's session saved (autosave_interval 1)
    timeout 60 "$VIBIDD" -c v.cfg 2> log &
    pid=$!
    PIDS+=("$pid")
    wait_status mqtt_published 'v >= 20' 10 || fail "nothing published: $(cat log)"
    kill -9 $BPID
    wait $BPID 2> /dev/null
    t_kill=$(date +%s%N)
    note "broker killed after $(status_val mqtt_published) acknowledged messages"
    if [ "$CASE" = restart ]; then sleep 3; else sleep 5; fi
    start_broker b.conf "$PORT"
    note "broker restarted after $((($(date +%s%N) - t_kill) / 1000000)) ms"
    wait $pid; rc=$?
    [ $rc -eq 0 ] || fail "exit status $rc: $(cat log)"
    # the broker has acknowledged every message vibidd sent; the subscriber gets the last of
    # them when the broker delivers it: wait for the last row's seq (up to 10 s) instead of a
    # fixed second (a CI run under load met a tail still on its way after 1 s)
    rows=$(($(grep -vc '^#' tracks.csv) - 1))
    for _ in $(seq 100); do
        grep -q "^$TOPIC/tracks {.*\"seq\":$rows," sub.out && break
        sleep 0.1
    done
    grep -q 'mqtt: connection to mqtt://127.0.0.1:[0-9]* lost' log || fail "no loss logged: $(grep mqtt log)"
    grep -q "mqtt: connected to .* again" log || fail "no reconnection: $(grep mqtt log)"
    [ "$(status_val mqtt_reconnects)" -ge 1 ] || fail "mqtt_reconnects $(status_val mqtt_reconnects)"
    if [ "$CASE" = restart ]; then
        [ "$(status_val mqtt_dropped)" = 0 ] || fail "dropped $(status_val mqtt_dropped) with a queue of 10000"
        out=$(check_tracks sub.out tracks.csv dups) || fail "after the restart: $out"
        note "broker restarted: $out"
    else
        d=$(status_val mqtt_dropped)
        [ "$d" -gt 0 ] || fail "no drop with a queue of 5 and a 5 s outage"
        python3 - sub.out tracks.csv "$TOPIC" "$d" << 'PYEOF' || fail "dropped_before"
import json, sys
msgs = {}
for l in open(sys.argv[1]):
    t, _, p = l.rstrip("\n").partition(" ")
    if t == sys.argv[3] + "/tracks":
        m = json.loads(p)
        msgs[m["seq"]] = m
rows = sum(1 for l in open(sys.argv[2]) if not l.startswith("#")) - 1
seqs = sorted(msgs)
gaps = 0
prev = 0
for s in seqs:
    if s != prev + 1:
        assert msgs[s]["dropped_before"] == s - prev - 1, (s, prev, msgs[s]["dropped_before"])
        gaps += s - prev - 1
    else:
        assert msgs[s]["dropped_before"] == 0, (s, msgs[s]["dropped_before"])
    prev = s
assert prev == rows, (prev, rows)
assert gaps == int(sys.argv[4]), (gaps, sys.argv[4])
print(f"{gaps} of {rows} rows dropped; every gap explained by dropped_before")
PYEOF
        note "queue of 5, 5 s outage: $d dropped (status), the message after each gap carries dropped_before = the gap"
    fi
    ;;
will)
    $GEN "$STAND" --duration 20 --noise 0.001 --seed 26 --csv cap.csv 2> /dev/null || fail "generator"
    PORT=$(free_port)
    broker_conf b.conf "$PORT" "allow_anonymous true"
    start_broker b.conf "$PORT"
    # with the metrics endpoint: the MQTT families are there and promtool accepts them
    config v.cfg "url = \"mqtt://127.0.0.1:$PORT\"; }; prometheus = { listen = \"127.0.0.1:0\";"
    "$VIBIDD" -c v.cfg 2> log & # not under timeout: kill -9 must hit vibidd (the capture bounds the run)
    pid=$!
    PIDS+=("$pid")
    wait_status mqtt_published 'v >= 5' 10 || fail "nothing published: $(cat log)"
    curl -s --max-time 2 -o m.txt "http://$(status_val metrics_listen)/metrics" || fail "scrape: curl exit $?"
    grep -q '^vibid_mqtt_connected 1$' m.txt || fail "metrics: $(grep vibid_mqtt m.txt)"
    grep -q '^vibid_mqtt_published_total [1-9]' m.txt || fail "metrics: $(grep vibid_mqtt m.txt)"
    command -v promtool > /dev/null || fail "promtool not found (Debian package prometheus: scripts/install-deps.sh --test)"
    promtool check metrics < m.txt > promtool.out 2>&1 || fail "promtool check metrics: $(cat promtool.out)"
    [ "$(retained_state -p "$PORT")" = running ] || fail "retained status while running: '$(retained_state -p "$PORT")'"
    kill -9 $pid
    wait $pid 2> /dev/null
    st=
    for _ in $(seq 20); do
        st=$(retained_state -p "$PORT")
        [ "$st" = offline ] && break
        sleep 0.2
    done
    [ "$st" = offline ] || fail "retained status after kill -9: '$st'"
    note "kill -9: the retained status went from running to offline (the last will)"
    ;;
drain_reconnect)
    # an unpaced replay of 100 rows ends in a fraction of a second, while vibidd's port has no
    # listener (connection refused: back-off); the proxy to the broker opens only once vibidd
    # logged the end of the capture, so every row is published by the drain
    $GEN "$STAND" --duration 10 --noise 0.001 --seed 27 --csv cap.csv 2> /dev/null || fail "generator"
    open_broker
    config v.cfg "url = \"mqtt://127.0.0.1:$PPORT\"; drain_timeout = 30.0;"
    sed -i 's/paced = true;/paced = false;/' v.cfg
    timeout 60 "$VIBIDD" -c v.cfg 2> log &
    pid=$!
    PIDS+=("$pid")
    wait_log log 'end of the capture reached' 20 || fail "the replay did not end: $(cat log)"
    wait_log log 'mqtt: cannot connect to' 10 || fail "no failed attempt before the proxy: $(grep mqtt log)"
    start_peer proxy.log proxy "$PPORT" "$BPORT"
    wait $pid; rc=$?
    [ $rc -eq 0 ] || fail "exit status $rc: $(cat log)"
    grep -q 'mqtt: every message acknowledged by the broker' log || fail "not drained: $(grep mqtt log)"
    sleep 0.3
    out=$(check_tracks sub.out tracks.csv) || fail "tracks: $out"
    [ "$(retained_state -p "$BPORT")" = stopped ] || fail "retained status: '$(retained_state -p "$BPORT")'"
    [ "$(status_val mqtt_unsent)" = 0 ] || fail "mqtt_unsent $(status_val mqtt_unsent)"
    note "replay ended while unreachable ($(status_val mqtt_connect_failures) failed attempts): the drain reconnected; $out; retained status stopped"
    ;;
flaps)
    $GEN "$STAND" --duration 6 --noise 0.001 --seed 28 --csv cap.csv 2> /dev/null || fail "generator"
    open_broker
    start_peer proxy.log proxy "$PPORT" "$BPORT" 0.2
    config v.cfg "url = \"mqtt://127.0.0.1:$PPORT\"; drain_timeout = 30.0;"
    timeout 90 "$VIBIDD" -c v.cfg 2> log; rc=$?
    [ $rc -eq 0 ] || fail "exit status $rc: $(cat log)"
    cuts=$(grep -c '^cut$' proxy.log)
    [ "$cuts" -ge 3 ] || fail "the proxy cut only $cuts connections: $(cat proxy.log)"
    grep -q 'mqtt: every message acknowledged by the broker' log || fail "not drained: $(grep mqtt log | tail -5)"
    sleep 0.3
    out=$(check_tracks sub.out tracks.csv dups) || fail "tracks: $out"
    [ "$(retained_state -p "$BPORT")" = stopped ] || fail "retained status: '$(retained_state -p "$BPORT")' (the will after a cut?)"
    [ "$(status_val mqtt_unsent)" = 0 ] || fail "mqtt_unsent $(status_val mqtt_unsent)"
    note "connections cut 200 ms after each connect ($cuts cuts, $(status_val mqtt_reconnects) reconnections): $out; retained status stopped"
    ;;
silent)
    $GEN "$STAND" --duration 30 --noise 0.001 --seed 29 --csv cap.csv 2> /dev/null || fail "generator"
    SPORT=$(free_port)
    start_peer silent.log silent "$SPORT"
    config v.cfg "url = \"mqtt://127.0.0.1:$SPORT\"; drain_timeout = 60.0;"
    timeout 120 "$VIBIDD" -c v.cfg 2> log &
    pid=$!
    PIDS+=("$pid")
    # the CONNACK time-out is 5 s: the first failure is counted after that (15 s: a loaded machine)
    wait_status mqtt_connect_failures 'v >= 1' 15 || fail "no failure counted: $(grep mqtt log)"
    grep -q "mqtt: cannot connect to mqtt://127.0.0.1:$SPORT: the peer accepted the connection but did not answer CONNECT within 5 s" log ||
        fail "message: $(grep mqtt log)"
    wait_status rows 'v >= 3' 10 || fail "no rows: $(cat log)"
    # 30 s: a liveness bound (drain_timeout is 60 s, and the peer will never answer)
    term_and_wait $pid 30
    [ $RC -eq 0 ] || fail "exit status $RC: $(tail -3 log)"
    grep -q 'mqtt: stopped with [0-9]* messages unsent .*the broker does not answer CONNECT' log || fail "end: $(grep mqtt log | tail -3)"
    rows=$(($(grep -vc '^#' tracks.csv) - 1))
    [ "$(status_val mqtt_unsent)" = "$rows" ] || fail "mqtt_unsent $(status_val mqtt_unsent), $rows rows were never sent"
    [ "$(status_val mqtt_published)" = 0 ] || fail "published to a silent peer?"
    note "silent peer: $(grep -o 'the peer accepted[^;]*' log | head -1); SIGTERM took $DT ms (drain_timeout 60 s), $rows rows counted unsent"
    ;;
*)
    fail "unknown case"
    ;;
esac
exit 0
