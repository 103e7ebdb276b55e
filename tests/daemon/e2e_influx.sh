#!/usr/bin/env bash
# End-to-end tests of vibidd's InfluxDB HTTP output (outputs.influx.http,
# daemon/src/influx_http.h) against a real server: Debian's influxdb (1.6), started by each
# case on free loopback ports with a data directory, authentication and (tls) a certificate
# of its own. What vibidd wrote is read back over the server's query API (/query, JSON,
# epoch=ns) and compared with the tracks CSV of the same run, row for row.
# usage: e2e_influx.sh CASE BUILD_DIR SOURCE_DIR
#   write     a paced replay with the server stopped (SIGTERM) for ~4 s mid-run and started
#             again: every row of the tracks CSV is in the database once, with the same time,
#             index, flags and values; the outage is counted (influx_http_failures > 0) and
#             nothing was dropped
#   auth      a wrong password: "credentials are refused" logged (HTTP 401), retried, the
#             lines kept; SIGTERM exits 0 within drain_timeout and says how many lines were not
#             written; a missing password file is a --check error naming the setting
#   rejected  a field type conflict (c1 already a string in the shard): HTTP 400, the lines are
#             counted as rejected, not retried, and the run ends normally
#   drops     a 1 MiB buffer and the server down for the first 2 s of a fast replay: the
#             buffer fills, lines are dropped and counted; each line after a gap carries
#             dropped_before = the number of CSV rows missing before it
#   tls       https with the test's CA (openssl): rows written; with another CA:
#             "certificate" in the error, retried, exit 0
#   body      a hostile server (tests/daemon/tools/hostile_peer.py) that streams a body of 1 GB
#             with every answer, three 500s then 200s: vibidd reads the first KiB of each and
#             closes (the server could send no more than the sockets' buffers), retries the
#             500s, writes every line (issue 30 item 4: it read all of it, 94 % of a core)
#   drain     SIGTERM while the server asks for a later try: 503 with Retry-After: 60 s, a
#             drain_timeout of 20 s: vibidd ends at once, the lines counted as not written,
#             instead of waiting 20 s for a try that cannot come; 500 without Retry-After
#             and a drain_timeout of 3 s: retries at the back-off until the next one would
#             come after the deadline, then ends (issue 30 item 7)
#   v2        API v2 (InfluxDB 2.x) against a recorder (python3 http.server, NOT an InfluxDB 2
#             server: Debian has none): POST /api/v2/write?org=..&bucket=..&precision=ns with
#             "Authorization: Token ..."; the recorded lines are the rows of the tracks CSV
. "$(dirname "$0")/e2e_common.sh" e2e_influx "$@"
GEN=$BUILD/tests/daemon/vd_gen_capture
STAND=$SRC/examples/stands/paper_example1.cfg

# Every case but v2 (a recorder stands in for an InfluxDB 2 server) needs influxd.
INFLUXD=$(command -v influxd || true)
if [ -z "$INFLUXD" ] && [ "$CASE" != v2 ]; then
    echo "SKIPPED [$CASE]: influxd is not installed (Debian package influxdb, scripts/install-deps.sh --test);"
    echo "SKIPPED [$CASE]: the InfluxDB test was NOT run"
    exit 77
fi

PIDS=()
cleanup() {
    exec 2> /dev/null # (bash's job notices of the servers killed here)
    for p in "${PIDS[@]}"; do kill -9 "$p"; done
    wait
    cd / && rm -rf "$W"
}
trap cleanup EXIT

. "$SRC/tests/support/influxd_conf.sh"
# server_conf PORT [HTTPS_LINES...]: influxd's configuration in $W/influx.conf, data under
# $W/influx, authentication on
server_conf() {
    local port=$1
    shift
    influxd_conf influx.conf "$W/influx" "$port" true "$@"
}

CURL_OPTS=()
# start_server: influxd with influx.conf; waits until /ping answers; sets SPID
start_server() {
    "$INFLUXD" -config influx.conf >> influxd.out 2>&1 &
    SPID=$!
    PIDS+=("$SPID")
    for _ in $(seq 100); do
        curl -s -o /dev/null "${CURL_OPTS[@]}" "$BASE/ping" && return 0
        kill -0 $SPID 2> /dev/null || fail "influxd exited: $(tail -5 influxd.out)"
        sleep 0.1
    done
    fail "influxd did not answer on $BASE: $(tail -5 influxd.out)"
}
stop_server() {
    kill -TERM "$SPID"
    wait "$SPID" 2> /dev/null
}

# q STATEMENT: the query API's JSON (as the admin)
q() { curl -s "${CURL_OPTS[@]}" -u admin:adm1n -XPOST "$BASE/query?epoch=ns" --data-urlencode "db=vibid" --data-urlencode "q=$1"; }

# setup_db: the admin (the first user of a server with authentication) and the database
setup_db() {
    curl -s "${CURL_OPTS[@]}" -XPOST "$BASE/query" --data-urlencode "q=CREATE USER admin WITH PASSWORD 'adm1n' WITH ALL PRIVILEGES" > /dev/null
    q "CREATE DATABASE vibid" | grep -q '"statement_id":0' || fail "CREATE DATABASE: $(q 'CREATE DATABASE vibid')"
    echo adm1n > pw.good
    echo wrong > pw.bad
    chmod 600 pw.good pw.bad
}

# config FILE HTTP_GROUP_BODY [ESTIMATOR_EXTRA] [EXTRA]: a paced replay of cap.csv with
# outputs.influx.http
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
# refine_every = 0: these cases check the transport row by row in sample order; the
# refinement's rows (a series of their own, estimate=refined) are checked in test_writers.c
estimator = { method = "rls"; prefilter_hz = 200.0; decimation = ${3:-100}; refine_every = 0; };
outputs = { tracks = { path = "tracks.csv"; }; status = { path = "status"; interval = 0.2; };
            influx = { site = "p1"; http = { $2 }; }; };
${4:-}
EOF
}


# check_rows TRACKS_CSV [gaps]: the database's vibid points against the CSV. Without "gaps":
# one point per row, equal time, index, flags and values (both are the same %.10g text of
# one double, so equal means ==). With "gaps": the points are a subset of the rows, and a
# point after missing rows carries dropped_before = their number.
check_rows() {
    q 'SELECT * FROM vibid' > db.json
    python3 - db.json "$1" "${2:-}" << 'PYEOF'
import csv, json, sys
res = json.load(open(sys.argv[1]))["results"][0]
gaps = sys.argv[3] == "gaps"
if "series" not in res:
    sys.exit(f"no points in the database: {res}")
s = res["series"][0]
pts = [dict(zip(s["columns"], v)) for v in s["values"]]
rows = list(csv.DictReader(l for l in open(sys.argv[2]) if not l.startswith("#")))
by_index = {int(r["index"]): r for r in rows}
def num(x):
    return None if x == "nan" else float(x)
assert all(p["stand"] == "paper_example1" and p["site"] == "p1" for p in pts), pts[0]
seen = [int(p["index"]) for p in pts]
if len(set(seen)) != len(seen):
    sys.exit("an index twice in the database")
if not gaps and len(pts) != len(rows):
    missing = sorted(set(by_index) - set(seen))
    sys.exit(f"{len(pts)} points for {len(rows)} rows; missing indices {missing[:10]}")
order = [int(r["index"]) for r in rows]
pos = {ix: k for k, ix in enumerate(order)}
prev = -1
dropped_total = 0
for p in pts:
    ix = int(p["index"])
    r = by_index.get(ix)
    if r is None:
        sys.exit(f"index {ix} is in the database but not in the tracks")
    t_ns = round(float(r["time_s"]) * 1e6) * 1000
    assert p["time"] == t_ns, (ix, p["time"], t_ns)
    for c in ("c1", "c1_se", "d", "d_se", "c2", "c2_se", "f1_hz", "f1_hz_se", "zeta1", "zeta1_se",
              "f2_hz", "f2_hz_se", "zeta2", "zeta2_se"):
        assert p[c] == num(r[c]), (ix, c, p[c], r[c])
    assert p["flags"] == r["flags"] and p["gap_samples"] == int(r["gap_samples"]), (ix, p["flags"], r["flags"])
    gap = pos[ix] - prev - 1
    db = p.get("dropped_before") or 0
    if gap != db:
        sys.exit(f"index {ix}: {gap} rows missing before it, dropped_before = {db}")
    dropped_total += gap
    prev = pos[ix]
tail = len(rows) - 1 - prev
print(f"{len(pts)} points of {len(rows)} rows, values equal; {dropped_total} dropped (each marked by "
      f"dropped_before), {tail} missing at the end")
PYEOF
}

PORT=$(free_port)
BASE=http://127.0.0.1:$PORT
GOOD="url = \"$BASE\"; username = \"admin\"; password_file = \"pw.good\"; batch_interval = 0.2;"

case $CASE in
write)
    $GEN "$STAND" --duration 30 --noise 0.001 --seed 31 --csv cap.csv 2> /dev/null || fail "generator"
    server_conf "$PORT"
    start_server
    setup_db
    config v.cfg "$GOOD"
    timeout 10 "$VIBIDD" -c v.cfg --check > check.out 2> check.err || fail "--check: $(cat check.err)"
    grep -q "^      url = \"$BASE\";" check.out || fail "--check printout: $(grep -A3 'http =' check.out)"
    timeout 90 "$VIBIDD" -c v.cfg --pace --speed 2 2> log &
    vpid=$!
    PIDS+=("$vpid")
    wait_status influx_http_written 'v >= 20' 10 || fail "nothing written: $(grep influx log)"
    stop_server
    sleep 4
    start_server
    wait $vpid
    rc=$?
    [ $rc -eq 0 ] || fail "exit status $rc: $(cat log)"
    grep -q 'influx http: writing to .* failed (no answer: .*connect' log ||
        fail "the outage is not logged: $(grep influx log)"
    grep -q 'influx http: written again after' log || fail "no recovery notice: $(grep influx log)"
    grep -q 'influx http: every line written' log || fail "not drained: $(grep influx log)"
    out=$(check_rows tracks.csv) || fail "database against the tracks: $out"
    note "$out"
    rows=$(grep -vc '^#' tracks.csv)
    [ "$(status_val influx_http_written)" = $((rows - 1)) ] || fail "influx_http_written $(status_val influx_http_written), $((rows - 1)) rows"
    [ "$(status_val influx_http_dropped)" = 0 ] || fail "influx_http_dropped $(status_val influx_http_dropped)"
    [ "$(status_val influx_http_rejected)" = 0 ] || fail "influx_http_rejected $(status_val influx_http_rejected)"
    f=$(status_val influx_http_failures)
    [ "$f" -ge 1 ] || fail "influx_http_failures $f: the outage was not seen"
    note "server stopped for 4 s mid-run: $f failed requests, retried; $(status_val influx_http_requests) requests written"
    ;;
auth)
    $GEN "$STAND" --duration 10 --noise 0.001 --seed 32 --csv cap.csv 2> /dev/null || fail "generator"
    server_conf "$PORT"
    start_server
    setup_db
    config nofile.cfg "url = \"$BASE\"; username = \"admin\"; password_file = \"pw.missing\";"
    timeout 10 "$VIBIDD" -c nofile.cfg --check > /dev/null 2> check.err && fail "--check accepted a missing password file"
    grep -q 'outputs.influx.http.password_file .*pw.missing: No such file' check.err || fail "--check message: $(cat check.err)"
    config bad.cfg "url = \"$BASE\"; username = \"admin\"; password_file = \"pw.bad\"; batch_interval = 0.2; drain_timeout = 1.0;"
    sed -i 's/^outputs = {/outputs = { prometheus = { listen = "127.0.0.1:0"; };/' bad.cfg
    timeout 60 "$VIBIDD" -c bad.cfg 2> log &
    vpid=$!
    PIDS+=("$vpid")
    wait_status influx_http_failures 'v >= 3' 15 || fail "failures with a wrong password: $(status_val influx_http_failures); $(cat log)"
    grep -q 'influx http: writing to .* failed (HTTP 401, the credentials are refused' log || fail "no clear error: $(grep influx log)"
    kill -0 $vpid || fail "vibidd exited on a wrong password: $(cat log)"
    # the same counters on the metrics endpoint, in an exposition promtool accepts
    curl -s "http://$(status_val metrics_listen)/metrics" > scrape.txt || fail "scrape of $(status_val metrics_listen)"
    if command -v promtool > /dev/null; then
        promtool check metrics < scrape.txt > promtool.out 2>&1 || fail "promtool check metrics: $(cat promtool.out)"
    else
        fail "promtool not found (Debian package prometheus: scripts/install-deps.sh --test)"
    fi
    awk '$1 == "vibid_influx_http_failures_total" && $2 >= 3 { ok = 1 } END { exit !ok }' scrape.txt ||
        fail "vibid_influx_http_failures_total: $(grep influx_http scrape.txt)"
    grep -q '^vibid_influx_http_ok 0$' scrape.txt || fail "vibid_influx_http_ok: $(grep influx_http_ok scrape.txt)"
    t0=$(date +%s.%N)
    kill -TERM $vpid
    wait $vpid || fail "exit status $? after SIGTERM"
    dt=$(awk -v a="$t0" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }')
    # a liveness bound, not a speed figure: drain_timeout is 1 s; a writer that waited for
    # its request's own time-out (10 s) or kept retrying would take 10 s or forever
    awk -v d="$dt" 'BEGIN { exit !(d < 5) }' || fail "SIGTERM took $dt s (drain_timeout 1 s)"
    grep -q 'influx http: stopped with [0-9]* lines not written' log || fail "the unwritten lines are not reported: $(grep influx log)"
    [ "$(status_val influx_http_written)" = 0 ] || fail "written with a wrong password?"
    res=$(q 'SELECT count(c1) FROM vibid')
    ! grep -q '"series"' <<< "$res" || fail "points in the database: $res"
    note "wrong password: $(grep -o 'HTTP 401[^;]*' log | head -1 | cut -c1-80)...; $(status_val influx_http_failures) failed requests, exit 0 in $dt s"
    ;;
rejected)
    $GEN "$STAND" --duration 10 --noise 0.001 --seed 33 --csv cap.csv 2> /dev/null || fail "generator"
    server_conf "$PORT"
    start_server
    setup_db
    # c1 a string in the shard of the capture's time: every row's float c1 conflicts
    t0=$(awk -F, 'NR == 2 { printf "%.0f", $1 * 1e9 }' cap.csv)
    curl -s -u admin:adm1n -XPOST "$BASE/write?db=vibid" --data-binary "vibid,site=p1,stand=other c1=\"text\" $t0" ||
        fail "pre-write"
    config v.cfg "$GOOD"
    timeout 60 "$VIBIDD" -c v.cfg --pace --speed 4 2> log || fail "exit status $?: $(cat log)"
    rows=$(($(grep -vc '^#' tracks.csv) - 1))
    [ "$(status_val influx_http_rejected)" = "$rows" ] || fail "influx_http_rejected $(status_val influx_http_rejected), $rows rows: $(grep influx log)"
    [ "$(status_val influx_http_failures)" = 0 ] || fail "rejected lines were retried: $(status_val influx_http_failures) failures"
    grep -q 'influx http: .* refused [0-9]* lines for good (HTTP 400: .*field type conflict' log ||
        fail "no clear error: $(grep influx log)"
    note "field type conflict: $rows lines rejected (HTTP 400), not retried, exit 0"
    ;;
drops)
    $GEN "$STAND" --duration 20 --noise 0.001 --seed 34 --csv cap.csv 2> /dev/null || fail "generator"
    server_conf "$PORT"
    start_server
    setup_db
    stop_server
    # decimation 1: 2000 rows/s of ~450 bytes at --speed 2 fill 1 MiB in ~0.6 s
    config v.cfg "$GOOD buffer_size = 1; batch_size = 2000; drain_timeout = 30.0;" 1
    timeout 120 "$VIBIDD" -c v.cfg --pace --speed 2 2> log &
    vpid=$!
    PIDS+=("$vpid")
    wait_status influx_http_dropped 'v >= 100' 10 || fail "no drops: $(cat status)"
    start_server
    wait $vpid || fail "exit status $?: $(cat log)"
    grep -q 'influx http: the buffer is full' log || fail "no warning: $(grep influx log)"
    out=$(check_rows tracks.csv gaps) || fail "database against the tracks: $out"
    note "$out"
    rows=$(($(grep -vc '^#' tracks.csv) - 1))
    w=$(status_val influx_http_written)
    d=$(status_val influx_http_dropped)
    [ $((w + d)) = "$rows" ] || fail "written $w + dropped $d != $rows rows"
    note "1 MiB buffer, server down 2 s: $w written, $d dropped and counted, of $rows rows"
    ;;
tls)
    $GEN "$STAND" --duration 10 --noise 0.001 --seed 35 --csv cap.csv 2> /dev/null || fail "generator"
    make_ca
    BASE=https://127.0.0.1:$PORT
    CURL_OPTS=(--cacert ca.pem)
    server_conf "$PORT" "https-enabled = true" "https-certificate = \"$W/server.pem\"" "https-private-key = \"$W/server.key\""
    start_server
    setup_db
    config v.cfg "url = \"$BASE\"; username = \"admin\"; password_file = \"pw.good\"; ca_file = \"ca.pem\"; batch_interval = 0.2;"
    timeout 60 "$VIBIDD" -c v.cfg --pace --speed 4 2> log || fail "exit status $?: $(cat log)"
    out=$(check_rows tracks.csv) || fail "database against the tracks over https: $out"
    note "https with the test's CA: $out"
    rm -f tracks.csv status
    config bad.cfg "url = \"$BASE\"; username = \"admin\"; password_file = \"pw.good\"; ca_file = \"other.pem\"; drain_timeout = 1.0;"
    timeout 60 "$VIBIDD" -c bad.cfg 2> log.bad &
    vpid=$!
    PIDS+=("$vpid")
    wait_status influx_http_failures 'v >= 2' 15 || fail "failures with the wrong CA: $(cat log.bad)"
    grep -q 'influx http: writing to https://.* failed (no answer: .*certificate' log.bad || fail "no clear TLS error: $(grep influx log.bad)"
    kill -TERM $vpid
    wait $vpid || fail "exit status $? after SIGTERM with the wrong CA"
    note "wrong CA: $(grep -o 'no answer: [^)]*' log.bad | head -1), retried, exit 0"
    ;;
body)
    $GEN "$STAND" --duration 10 --noise 0.001 --seed 37 --csv cap.csv 2> /dev/null || fail "generator"
    start_peer peer.log http "$PORT" "500:1073741824,500:1073741824,500:1073741824,200:1073741824"
    config v.cfg "url = \"$BASE\"; batch_interval = 0.2;"
    # vibidd's CPU time (user, system) and the run's wall time: printed, not asserted
    (TIMEFORMAT='%U %S %R'; time timeout 90 "$VIBIDD" -c v.cfg --pace --speed 4 2> log) 2> time.txt; rc=$?
    [ $rc -eq 0 ] || fail "exit status $rc: $(grep influx log)"
    cpu=$(awk '{ printf "%.2f s of CPU in %.1f s (%.0f %% of a core)", $1 + $2, $3, 100 * ($1 + $2) / $3 }' time.txt)
    rows=$(($(grep -vc '^#' tracks.csv) - 1))
    [ "$(status_val influx_http_written)" = "$rows" ] || fail "influx_http_written $(status_val influx_http_written) of $rows: $(grep influx log)"
    [ "$(status_val influx_http_failures)" = 3 ] || fail "influx_http_failures $(status_val influx_http_failures), the plan had 3 500s"
    grep -q 'influx http: writing to .* failed (HTTP 500: {"error":"xxx.*\[\.\.\. the rest of the answer was not read\]' log ||
        fail "the 500's message: $(grep influx log | head -3)"
    # each answer's body: the server could hand the kernel its socket buffers' worth (a few
    # MiB on loopback: tcp_wmem + tcp_rmem) before vibidd closed; 64 MiB is far above that and
    # far below the 1 GiB that reading it whole takes
    python3 - peer.log << 'PYEOF' || fail "bodies: $(cat peer.log)"
import sys
sent = [int(l.split()[5]) for l in open(sys.argv[1]) if l.startswith("request ")]
assert len(sent) >= 4, sent
assert max(sent) < 64 << 20, sent
print(f"{len(sent)} answers of 1 GiB each; at most {max(sent) / 2**20:.1f} MiB of one was sent before vibidd closed")
PYEOF
    note "$(python3 -c 'import sys; s=[int(l.split()[5]) for l in open("peer.log") if l.startswith("request ")]; print(f"{len(s)} answers with a 1 GiB body: at most {max(s) / 2**20:.1f} MiB of one taken before vibidd closed")'); 3 500s retried, $rows of $rows lines written; vibidd: $cpu"
    ;;
drain)
    $GEN "$STAND" --duration 60 --noise 0.001 --seed 38 --csv cap.csv 2> /dev/null || fail "generator"
    # against PLAN (hostile_peer.py http) with drain_timeout DRAIN: a paced replay until the
    # first failed request (sets vpid, n0: the requests before SIGTERM)
    until_failure() {
        rm -f peer.log status tracks.csv
        start_peer peer.log http "$PORT" "$1"
        config v.cfg "url = \"$BASE\"; batch_interval = 0.2; drain_timeout = $2;"
        timeout 90 "$VIBIDD" -c v.cfg --pace 2> log &
        vpid=$!
        PIDS+=("$vpid")
        wait_status influx_http_failures 'v >= 1' 15 || fail "no failure: $(grep influx log)"
        n0=$(grep -c '^request ' peer.log)
    }
    until_failure "503:0:60" 20.0
    # 10 s: a liveness bound (the drain may last 20 s; Retry-After, 60 s of which 30 s are
    # honoured, puts every later try after that)
    term_and_wait $vpid 10
    [ $RC -eq 0 ] || fail "exit status $RC: $(grep influx log)"
    grep -q 'influx http: stopped with [0-9]* lines not written .*its next try was due after the deadline' log ||
        fail "end: $(grep influx log | tail -3)"
    [ "$(grep -c '^request ' peer.log)" = 1 ] || fail "requests: $(cat peer.log)"
    left=$(status_val influx_http_waiting)
    rows=$(($(grep -vc '^#' tracks.csv) - 1))
    [ "$left" = "$rows" ] || fail "influx_http_waiting $left after the drain, $rows rows never written"
    note "503 with Retry-After 60: SIGTERM ended in $DT ms (drain_timeout 20 s), $left lines counted as not written, 1 request"
    # without Retry-After: tries at the back-off (0.5, 1, 2 s ...) while they fit drain_timeout 3 s
    kill -9 $PEERPID 2> /dev/null
    wait $PEERPID 2> /dev/null
    until_failure "500" 3.0
    term_and_wait $vpid 10
    [ $RC -eq 0 ] || fail "exit status $RC: $(grep influx log)"
    n1=$(grep -c '^request ' peer.log)
    [ $((n1 - n0)) -ge 1 ] || fail "no retry during the drain: $n0 requests before SIGTERM, $n1 after"
    grep -q 'influx http: stopped with [0-9]* lines not written .*its next try was due after the deadline' log ||
        fail "end: $(grep influx log | tail -3)"
    note "500 without Retry-After, drain_timeout 3 s: $((n1 - n0)) retries during the drain, then ended in $DT ms (the next one was due after the deadline)"
    ;;
v2)
    $GEN "$STAND" --duration 10 --noise 0.001 --seed 36 --csv cap.csv 2> /dev/null || fail "generator"
    echo "t0k3n-for-vibid" > token
    chmod 600 token
    python3 - "$PORT" > recorder.out 2>&1 << 'PYEOF' &
import http.server, sys
class H(http.server.BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    def do_POST(self):
        body = self.rfile.read(int(self.headers["Content-Length"]))
        ok = self.headers.get("Authorization") == "Token t0k3n-for-vibid"
        with open("requests.log", "a") as f:
            f.write(f"{self.path} {self.headers.get('Authorization')} {len(body)}\n")
        if ok:
            with open("lines.txt", "ab") as f:
                f.write(body)
        msg = b"" if ok else b'{"code":"unauthorized","message":"unauthorized access"}'
        self.send_response(204 if ok else 401)
        self.send_header("Content-Length", str(len(msg)))
        self.end_headers()
        self.wfile.write(msg)
    def log_message(self, *a):
        pass
http.server.ThreadingHTTPServer(("127.0.0.1", int(sys.argv[1])), H).serve_forever()
PYEOF
    PIDS+=($!)
    for _ in $(seq 50); do curl -s -o /dev/null -XPOST -d x "$BASE/probe" && break; sleep 0.1; done
    config v.cfg "url = \"$BASE/\"; api = \"v2\"; org = \"plant 1\"; bucket = \"vibid/raw\"; token_file = \"token\"; batch_interval = 0.2;"
    timeout 60 "$VIBIDD" -c v.cfg --pace --speed 4 2> log || fail "exit status $?: $(cat log)"
    grep -v '^/probe' requests.log | awk '{ print $1, $2, $3 }' | sort -u | head -3 > req.seen
    grep -q '^/api/v2/write?org=plant%201&bucket=vibid%2Fraw&precision=ns Token t0k3n-for-vibid$' req.seen ||
        fail "requests: $(cat requests.log | head -3)"
    rows=$(($(grep -vc '^#' tracks.csv) - 1))
    [ "$(grep -c '^vibid,site=p1,stand=paper_example1 ' lines.txt)" = "$rows" ] || fail "$(wc -l < lines.txt) lines for $rows rows"
    note "API v2 (a recorder, not an InfluxDB 2 server): $(head -1 req.seen); $rows lines for $rows rows"
    ;;
*)
    fail "unknown case $CASE"
    ;;
esac
echo "PASS [$CASE]"
