#!/usr/bin/env bash
# End-to-end tests of the vibidd binary on captures of the paper's example 1.
# usage: e2e.sh CASE BUILD_DIR SOURCE_DIR
# Captures come from tests/daemon/tools/vd_gen_capture (RK4 simulation of the stand
# file's true values: c1 = 2.5e5 N/m, d = 300 N s/m, c2 = 1.5e6 N/m). Every run is
# bounded with `timeout`; only 127.0.0.1 is used.
. "$(dirname "$0")/e2e_common.sh" e2e "$@"
GEN=$BUILD/tests/daemon/vd_gen_capture
STAND=$SRC/examples/stands/paper_example1.cfg
DBC=$SRC/tests/daemon/data/example1.dbc
SIMCFG=$SRC/tests/daemon/data/sim_steady.cfg

# config_csv FILE EXTRA: a replay configuration of a CSV capture
config_csv() {
    cat > "$1" <<EOF
stand = "$STAND";
source = {
  kind = "replay"; file = "cap.csv"; time_column = "t";
  channels = (
    { name = "x1"; quantity = "displacement"; node = 0; unit = "m"; column = "x1"; },
    { name = "x2"; quantity = "displacement"; node = 1; unit = "m"; column = "x2"; },
    { name = "s";  quantity = "base_displacement"; node = 0; unit = "m"; column = "s"; }
  );
};
estimator = { method = "rls"; prefilter_hz = 200.0; decimation = 200; };
outputs = { tracks = { path = "tracks.csv"; }; status = { path = "status"; interval = 0.2; }; };
$2
EOF
}

# config_modbus FILE PORT: FIFO mode against vibid-sim's default register map
config_modbus() {
    cat > "$1" <<EOF
stand = "$STAND";
source = {
  kind = "modbus"; url = "tcp://127.0.0.1:$2"; mode = "fifo"; poll_period = 0.02;
  response_timeout = 0.2; backoff_initial = 0.05; backoff_max = 0.4;
  registers = (
    { name = "x1"; address = 0; type = "FLOAT32"; byte_order = "ABCD"; },
    { name = "x2"; address = 2; type = "FLOAT32"; byte_order = "ABCD"; },
    { name = "s";  address = 4; type = "FLOAT32"; byte_order = "ABCD"; }
  );
  channels = (
    { name = "x1"; quantity = "displacement"; node = 0; unit = "m"; register = "x1"; },
    { name = "x2"; quantity = "displacement"; node = 1; unit = "m"; register = "x2"; },
    { name = "s";  quantity = "base_displacement"; node = 0; unit = "m"; register = "s"; }
  );
};
estimator = { method = "rls"; prefilter_hz = 200.0; decimation = 200; };
outputs = { tracks = { path = "tracks.csv"; }; record = { path = "raw.csv"; };
            status = { path = "status"; interval = 0.2; }; };
EOF
}

# start_sim ARGS...: vibid-sim serving the stand over Modbus TCP (start_sim_modbus); sets SIMPID, PORT
start_sim() { start_sim_modbus -c "$STAND" -s "$SIMCFG" "$@"; }

config_candump() {
    cat > "$1" <<EOF
stand = "$STAND";
source = {
  kind = "replay"; file = "cap.log"; dbc = "$DBC"; counter = "Counter";
  channels = (
    { name = "x1"; quantity = "displacement"; node = 0; unit = "m"; signal = "X1"; message = "Sample_A"; },
    { name = "x2"; quantity = "displacement"; node = 1; unit = "m"; signal = "X2"; message = "Sample_B"; },
    { name = "s";  quantity = "base_displacement"; node = 0; unit = "m"; signal = "S"; message = "Sample_C"; }
  );
};
estimator = { method = "rls"; prefilter_hz = 200.0; decimation = 200; };
outputs = { tracks = { path = "tracks.csv"; }; influx = { path = "tracks.influx"; };
            status = { path = "status"; interval = 0.2; }; };
$2
EOF
}

# check_final TRACKS TOL_PERCENT: last row's c1, d, c2 against the truth
check_final() {
    awk -F, -v tol="$2" 'NR > 1 { c1 = $3; d = $5; c2 = $7 } END {
        e1 = 100 * (c1 - 2.5e5) / 2.5e5; e2 = 100 * (d - 300) / 300; e3 = 100 * (c2 - 1.5e6) / 1.5e6;
        printf "final: c1 = %.1f (%+.3f %%), d = %.3f (%+.3f %%), c2 = %.1f (%+.3f %%)\n", c1, e1, d, e2, c2, e3;
        bad = (e1 > tol || -e1 > tol || e2 > tol || -e2 > tol || e3 > tol || -e3 > tol || c1 == "");
        exit bad }' "$1" || fail "final estimates not within $2 % of the truth"
}

# data_rows FILE: the recursive estimator's track rows of a tracks file (not the "#" lines of
# the estimator's choices, not the column header, not the refinement's rows flagged W)
data_rows() { grep -v '^#' "$1" | awk -F, 'NR > 1 && $NF !~ /W/' | wc -l; }

# rate_stand HZ FILE: the stand with another sample_rate (captures at that rate)
rate_stand() {
    sed "s/^\( *sample_rate = \)2000\.0;/\1$1;/" "$STAND" > "$2"
    grep -q "sample_rate = $1;" "$2" || fail "test setup: sample_rate not replaced in $2"
}

# config_prometheus FILE: config_csv with outputs.prometheus on a port the kernel picks
config_prometheus() {
    config_csv "$1" ""
    sed -i 's|^outputs = { tracks = { path = "tracks.csv"; }; status = { path = "status"; interval = 0.2; }; };|outputs = { tracks = { path = "tracks.csv"; }; status = { path = "status"; interval = 0.2; };\n            prometheus = { listen = "127.0.0.1:0"; }; };|' "$1"
    grep -q 'prometheus = { listen = "127.0.0.1:0"; }' "$1" || fail "test setup: prometheus group not inserted in $1"
}

# wait_metrics_listen: the endpoint's address from the status file (metrics_listen), 5 s at most
wait_metrics_listen() {
    local t
    for _ in $(seq 50); do
        t=$(status_val metrics_listen status 2>/dev/null)
        [ -n "$t" ] && { echo "$t"; return 0; }
        sleep 0.1
    done
    return 1
}

# metric NAME FILE: the value of the sample NAME (with its labels) in an exposition
metric() { awk -v n="$1" '$1 == n { print $2 }' "$2"; }

# prom_query API QUERY: the first result's value from Prometheus' query API ("" if none)
prom_query() {
    curl -s --max-time 2 -G "$1" --data-urlencode "query=$2" | python3 -c '
import json, sys
try:
    r = json.load(sys.stdin)["data"]["result"]
    print(r[0]["value"][1] if r else "")
except Exception:
    print("")'
}

case $CASE in
replay_csv)
    # 20 s at 2 kHz, noise 0.1 % of RMS on every channel; tolerance 1 % (issue 7); the
    # central-difference bias alone is about 0.2 % at this rate (stand-file.md).
    $GEN "$STAND" --duration 20 --noise 0.001 --seed 1 --csv cap.csv 2>/dev/null || fail "generator"
    config_csv v.cfg ""
    timeout 60 "$VIBIDD" -c v.cfg 2> log || fail "vibidd exit $? ($(cat log))"
    final=$(check_final tracks.csv 1.0) || exit 1; note "$final"
    rows=$(data_rows tracks.csv)
    [ "$rows" -eq 200 ] || fail "expected 200 rows (40000 samples / 200), got $rows"
    [ "$(status_val state status)" = stopped ] || fail "status state"
    [ "$(status_val samples status)" = 40000 ] || fail "status samples"
    # a replay waits for room in the ring and drops nothing: no overflows in its status
    # (before, every wait counted as one; issue 12, item 10)
    [ "$(status_val ring_overflows status)" = 0 ] ||
        fail "ring_overflows $(status_val ring_overflows status) in a replay (replay_waits $(status_val replay_waits status))"
    note "replay_waits $(status_val replay_waits status), ring_overflows 0"
    ;;
replay_candump)
    $GEN "$STAND" --duration 20 --noise 0.001 --seed 2 --candump cap.log 2>/dev/null || fail "generator"
    config_candump v.cfg ""
    timeout 60 "$VIBIDD" -c v.cfg 2> log || fail "vibidd exit $? ($(cat log))"
    final=$(check_final tracks.csv 1.0) || exit 1; note "$final"
    rows=$(data_rows tracks.csv)
    [ "$rows" -eq 200 ] || fail "expected 200 rows, got $rows"
    # every row, the refinement's (flag W) too, is one line
    [ "$(wc -l < tracks.influx)" -eq "$(grep -v '^#' tracks.csv | tail -n +2 | wc -l)" ] || fail "influx lines != rows"
    [ "$(grep -c 'flags="[A-Z]*W' tracks.influx)" -eq "$(grep -v '^#' tracks.csv | awk -F, '$NF ~ /W/' | wc -l)" ] ||
        fail "the refined rows are not flagged W in InfluxDB"
    grep -q '^vibid,stand=paper_example1 c1=[0-9.e+]*,c1_se=' tracks.influx || fail "influx format"
    [ "$(status_val source_frames status)" = 120000 ] || fail "frames: $(status_val source_frames status)"
    ;;
record_replay)
    # "live" = paced replay at 10x (the acquisition thread runs on the clock as with a
    # bus), recorded as CSV; the fast replay of the recording must give the same tracks,
    # byte for byte. Also through the candump path.
    $GEN "$STAND" --duration 10 --noise 0.001 --seed 3 --candump cap.log 2>/dev/null || fail "generator"
    config_candump v.cfg ""
    timeout 60 "$VIBIDD" -c v.cfg --pace --speed 10 --record raw.csv --tracks live.csv 2> log || fail "live run: $(cat log)"
    timeout 60 "$VIBIDD" -c v.cfg --replay raw.csv --tracks replay.csv --status "" 2> log2 || fail "replay: $(cat log2)"
    [ "$(data_rows live.csv)" -gt 90 ] || fail "too few rows"
    cmp live.csv replay.csv || fail "replayed tracks differ from the live tracks"
    note "live and replayed tracks identical ($(data_rows live.csv) rows, sha256 $(sha256sum < live.csv | cut -c1-16))"
    # The same with the automatic estimator (block IV, discretization check). A row's
    # estimate is computed from the estimator's state kept at its sample: paced, when the
    # ring has run empty right after it; replayed as fast as possible, only when the next
    # row is due (daemon.c, finish_row). Identical tracks say that when a row is finished
    # does not matter (that the kept state is the estimator's own, bit for bit: ident.twin).
    sed 's/^estimator = .*/estimator = { decimation = 200; };/' v.cfg > auto.cfg
    grep -q '^estimator = { decimation = 200; };' auto.cfg || fail "test setup: estimator line not replaced"
    timeout 60 "$VIBIDD" -c auto.cfg --pace --speed 10 --record raw_auto.csv --tracks live_auto.csv 2> log ||
        fail "live run, automatic estimator: $(cat log)"
    timeout 60 "$VIBIDD" -c auto.cfg --replay raw_auto.csv --tracks replay_auto.csv --status "" 2> log2 ||
        fail "replay, automatic estimator: $(cat log2)"
    grep -q '^# estimator: instrumental variables with block statistics' live_auto.csv ||
        fail "automatic estimator not chosen: $(head -1 live_auto.csv)"
    [ "$(data_rows live_auto.csv)" -gt 90 ] || fail "too few rows (automatic estimator)"
    cmp live_auto.csv replay_auto.csv || fail "automatic estimator: replayed tracks differ from the live tracks"
    note "automatic estimator: live and replayed tracks identical ($(data_rows live_auto.csv) rows)"
    ;;
record_candump)
    # The raw recording as a candump log (outputs.record.format = "candump"): a paced "live"
    # run over a capture with 1 % of its frames dropped (so there are gaps) records each
    # sample as the DBC's three frames with the sample counter; replaying that log with the
    # same configuration must give the same tracks byte for byte, with the same samples missing.
    $GEN "$STAND" --duration 10 --noise 0.001 --seed 5 --drop 0.01 --candump cap.log 2>/dev/null || fail "generator"
    config_candump v.cfg ""
    sed 's|^outputs = { tracks = { path = "tracks.csv"; };|outputs = { tracks = { path = "tracks.csv"; }; record = { path = "raw.log"; format = "candump"; };|' \
        v.cfg > rec.cfg
    grep -q 'format = "candump"' rec.cfg || fail "test setup: record group not inserted"
    timeout 60 "$VIBIDD" -c rec.cfg --pace --speed 10 --tracks live.csv 2> log || fail "live run: $(cat log)"
    live_gaps=$(status_val gaps status) live_samples=$(status_val samples status)
    live_missing=$(status_val missing_samples status)
    [ "$live_gaps" -gt 10 ] || fail "expected gaps from the dropped frames, got $live_gaps"
    # every recorded line is a frame of the DBC, three per sample, the counter in byte 0..1
    lines=$(wc -l < raw.log)
    [ "$lines" -eq $((3 * live_samples)) ] || fail "raw.log: $lines lines for $live_samples samples"
    head -1 raw.log | grep -Eq '^\([0-9]+\.[0-9]{6}\) can0 10[012]#[0-9A-F]{16}$' || fail "raw.log format: $(head -1 raw.log)"
    sed 's|file = "cap.log"|file = "raw.log"|' v.cfg > replay.cfg
    timeout 60 "$VIBIDD" -c replay.cfg --tracks replay.csv 2> log2 || fail "replay: $(cat log2)"
    cmp live.csv replay.csv || fail "replayed tracks differ from the live tracks"
    # the same samples missing; adjacent incomplete samples may be one gap record instead of
    # several (a counter jump), so the count of gap records may be smaller
    [ "$(status_val missing_samples status)" = "$live_missing" ] ||
        fail "missing samples: live $live_missing, replay $(status_val missing_samples status)"
    [ "$(status_val samples status)" = "$live_samples" ] || fail "samples differ"
    note "candump recording: $live_samples samples, $live_missing missing ($live_gaps gaps), $lines frames; replayed tracks identical ($(data_rows live.csv) rows)"
    ;;
start_values)
    # estimator.start_values reach the RLS (vibid_ident_set_prior): c1 starts 20 % low.
    # With a strong prior (rls_alpha = 1e3: P0 = 1e-3 I against data information of
    # about 1e-4 per 200 samples, in m^2) the first row stays at the start value (0.5 %);
    # with the default weak prior (1e-9) the wrong start is forgotten and the final
    # estimates are within the issue's 1 %.
    $GEN "$STAND" --duration 20 --noise 0.001 --seed 6 --csv cap.csv 2>/dev/null || fail "generator"
    start='start_values = ( { name = "c1"; value = 2.0e5; } );'
    config_csv v.cfg ""
    sed -i "s|^estimator = { method = \"rls\";|estimator = { method = \"rls\"; rls_alpha = 1e3; $start|" v.cfg
    grep -q 'rls_alpha = 1e3' v.cfg || fail "test setup: estimator line not changed"
    timeout 60 "$VIBIDD" -c v.cfg 2> log || fail "vibidd exit $? ($(cat log))"
    first=$(grep -v '^#' tracks.csv | awk -F, 'NR == 2 { print $3 }')
    awk -v c="$first" 'BEGIN { exit !(c > 0.995 * 2.0e5 && c < 1.005 * 2.0e5) }' ||
        fail "strong prior: first row c1 = $first, expected the start value 2.0e5 within 0.5 %"
    config_csv w.cfg ""
    sed -i "s|^estimator = { method = \"rls\";|estimator = { method = \"rls\"; $start|" w.cfg
    rm -f tracks.csv
    timeout 60 "$VIBIDD" -c w.cfg 2> log || fail "vibidd exit $? ($(cat log))"
    final=$(check_final tracks.csv 1.0) || exit 1
    note "strong prior: first row c1 = $first (start 2.0e5); weak prior: $final"
    ;;
gaps_faults)
    # dropped (1 %) and corrupted (0.5 %) frames: every one counted, gaps flagged in the
    # tracks, estimates still within 1 %.
    $GEN "$STAND" --duration 20 --noise 0.001 --seed 4 --drop 0.01 --corrupt 0.005 --candump cap.log 2>/dev/null \
        || fail "generator"
    config_candump v.cfg ""
    timeout 60 "$VIBIDD" -c v.cfg 2> log || fail "vibidd exit $?"
    gaps=$(status_val gaps status)
    missing=$(status_val missing_samples status)
    bad=$(status_val source_bad_lines status)
    samples=$(status_val samples status)
    note "samples $samples, gaps $gaps, missing $missing, bad lines $bad, faults $(status_val faults status)"
    [ "$gaps" -gt 100 ] || fail "expected many gaps"
    [ "$bad" -gt 100 ] || fail "expected bad lines counted"
    [ $((samples + missing)) -eq 40000 ] || fail "samples + missing != 40000: nothing may vanish"
    grep -q ',G[A-Z]*$' tracks.csv || fail "no row flagged G"
    grep -q 'source fault (bad_line' log || fail "bad lines not logged"
    final=$(check_final tracks.csv 1.0) || exit 1; note "$final"
    ;;
truncated)
    $GEN "$STAND" --duration 5 --seed 5 --csv cap.csv --truncate 2>/dev/null || fail "generator"
    config_csv v.cfg ""
    timeout 60 "$VIBIDD" -c v.cfg 2> log || fail "vibidd exit $? on a truncated capture"
    grep -q 'truncated capture' log || fail "truncation not reported: $(cat log)"
    [ "$(status_val samples status)" = 9999 ] || fail "expected 9999 samples (last line cut)"
    [ "$(status_val faults status)" = 1 ] || fail "expected 1 fault"
    note "truncated last line reported: $(grep -m1 truncated log)"
    ;;
bad_config)
    config_csv v.cfg "alarms = {
  test = \"threshold\"; threshold = -1.0;
};"
    timeout 10 "$VIBIDD" -c v.cfg 2> log; rc=$?
    [ $rc -eq 2 ] || fail "exit status $rc, expected 2"
    grep -q "v.cfg:13: alarms.threshold: -1 outside \[0.1, 1e+06\]" log || fail "message: $(cat log)"
    note "$(cat log)"
    timeout 10 "$VIBIDD" -c nonexistent.cfg 2> log; rc=$?
    [ $rc -eq 2 ] && grep -q "nonexistent.cfg: cannot read" log || fail "missing file: rc $rc $(cat log)"
    # a directory given as the configuration says so (it said "No such file or directory")
    mkdir cfgdir
    timeout 10 "$VIBIDD" -c cfgdir 2> log; rc=$?
    [ $rc -eq 2 ] && grep -q "cfgdir: cannot read: Is a directory" log || fail "a directory: rc $rc $(cat log)"
    config_csv v2.cfg ""
    timeout 10 "$VIBIDD" -c v2.cfg 2> log; rc=$?  # cap.csv does not exist
    [ $rc -eq 2 ] && grep -q "cap.csv" log || fail "missing capture: rc $rc $(cat log)"
    note "$(cat log)"
    timeout 10 "$VIBIDD" -c v2.cfg --speed fast 2> log; rc=$?
    [ $rc -eq 2 ] || fail "bad option accepted"
    ;;
signals)
    # paced replay of 60 s: SIGHUP after the tracks file was moved away must create a new
    # one; SIGTERM must drain, flush and exit 0 within a second.
    $GEN "$STAND" --duration 60 --seed 6 --csv cap.csv 2>/dev/null || fail "generator"
    config_csv v.cfg ""
    timeout 30 "$VIBIDD" -c v.cfg --pace 2> log &
    pid=$!
    sleep 1.5
    mv tracks.csv tracks.old
    kill -HUP $pid
    sleep 1.0
    [ -f tracks.csv ] || fail "SIGHUP did not reopen tracks.csv"
    kill -TERM $pid
    t0=$(date +%s%N)
    wait $pid; rc=$?
    dt=$((($(date +%s%N) - t0) / 1000000))
    [ $rc -eq 0 ] || fail "exit status $rc after SIGTERM: $(cat log)"
    [ $dt -lt 2000 ] || fail "took $dt ms to stop"
    [ "$(status_val state status)" = stopped ] || fail "status not final"
    # the ring's high water: a paced replay at 2 kHz hands over a read's batch (at most 64
    # records) at a time to an estimator that keeps up, so far below the 4096 records of the
    # replay's ring, which the old measure (records pushed since the producer last looked at
    # the tail) reached after 2 s. Half the ring is 1 s of the estimator stalled.
    hw=$(status_val ring_high_water status)
    [ "$hw" -ge 1 ] && [ "$hw" -le 2048 ] || fail "ring_high_water $hw of $(status_val ring_capacity status) on a paced replay"
    grep -v '^#' tracks.csv | head -1 | grep -q '^time_s,index,c1' || fail "reopened file has no header"
    samples=$(status_val samples status)
    rows=$(( $(data_rows tracks.old) + $(data_rows tracks.csv) ))
    [ $rows -eq $((samples / 200)) ] || fail "rows $rows != samples $samples / 200: not flushed"
    grep -q 'outputs reopened (SIGHUP)' log || fail "no reopen log"
    grep -q 'SIGTERM received' log || fail "no SIGTERM log"
    note "stopped $dt ms after SIGTERM; $samples samples, $rows rows in both files"
    ;;
notify)
    # sd_notify: READY=1 at start, WATCHDOG=1 pings (WATCHDOG_USEC = 0.4 s), STOPPING=1.
    $GEN "$STAND" --duration 30 --seed 7 --csv cap.csv 2>/dev/null || fail "generator"
    config_csv v.cfg ""
    python3 - "$W/notify.sock" > notes.txt <<'EOF' &
import socket, sys, time
s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
s.bind(sys.argv[1]); s.settimeout(10.0)
end = time.time() + 10.0
while time.time() < end:
    try:
        print(s.recv(4096).decode().replace("\n", "|"), flush=True)
    except socket.timeout:
        break
EOF
    py=$!
    for _ in $(seq 100); do [ -S notify.sock ] && break; sleep 0.1; done  # listener bound
    [ -S notify.sock ] || fail "notify listener did not start"
    NOTIFY_SOCKET=$W/notify.sock WATCHDOG_USEC=400000 timeout 30 "$VIBIDD" -c v.cfg --pace 2> log &
    pid=$!
    sleep 2
    kill -TERM $pid
    wait $pid || fail "exit status"
    sleep 0.2
    kill $py 2>/dev/null; wait $py 2>/dev/null
    grep -q '^READY=1' notes.txt || fail "no READY=1: $(cat notes.txt)"
    n=$(grep -c '^WATCHDOG=1' notes.txt)
    [ "$n" -ge 5 ] || fail "only $n watchdog pings in 2 s at 0.2 s intervals"
    grep -q '^STOPPING=1' notes.txt || fail "no STOPPING=1"
    note "READY, $n WATCHDOG pings, STOPPING received"
    ;;
influx_udp)
    $GEN "$STAND" --duration 5 --seed 8 --csv cap.csv 2>/dev/null || fail "generator"
    python3 - > udp.txt <<'EOF' &
import socket
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.bind(("127.0.0.1", 0)); s.settimeout(5.0)
open("port", "w").write(str(s.getsockname()[1]))
n = 0
try:
    while True:
        d = s.recv(65536).decode()
        n += d.count("\n")
        print(d, end="", flush=True)
except socket.timeout:
    pass
EOF
    py=$!
    for _ in 1 2 3 4 5 6 7 8 9 10; do [ -s port ] && break; sleep 0.1; done
    config_csv v.cfg ""
    sed -i "s/^outputs = { tracks = { path = \"tracks.csv\"; };/outputs = { tracks = { path = \"tracks.csv\"; }; influx = { udp = \"127.0.0.1:$(cat port)\"; };/" v.cfg
    timeout 30 "$VIBIDD" -c v.cfg 2> log || fail "vibidd: $(cat log)"
    sleep 0.5
    kill $py 2>/dev/null; wait $py 2>/dev/null
    lines=$(grep -c '^vibid,stand=' udp.txt)
    [ "$lines" -eq 50 ] || fail "expected 50 line-protocol datagrams, got $lines"
    note "$lines line-protocol datagrams received on 127.0.0.1"
    ;;
diagnostics)
    # c2 drops by 10 % at t = 40 s (a crack). RLS with forgetting 0.999 (memory ~1000
    # samples = 0.5 s) tracks it; the alarm (baseline learned over 10..25 s, 5 standard
    # errors and 3 %, held 1 s) must fire after 40 s and not before.
    $GEN "$STAND" --duration 60 --noise 0.002 --seed 9 --step c2:0.9:40 --csv cap.csv 2>/dev/null || fail "generator"
    config_csv v.cfg 'alarms = { test = "threshold"; threshold = 5.0; min_relative = 0.03; hold = 1.0; learn_start = 10.0;
  learn_duration = 15.0; parameters = ( { name = "c1"; }, { name = "d"; }, { name = "c2"; } ); };'
    sed -i 's/method = "rls";/method = "rls"; forgetting = 0.999;/' v.cfg
    sed -i 's/tracks = { path = "tracks.csv"; };/tracks = { path = "tracks.csv"; }; influx = { path = "alarms.influx"; };/' v.cfg
    timeout 60 "$VIBIDD" -c v.cfg 2> log || fail "vibidd: $(cat log)"
    grep 'ALARM' log | head -3
    first=$(grep -m1 '^vibid_alarm,' alarms.influx | sed 's/.*index=\([0-9]*\)i.*/\1/')
    [ -n "$first" ] || fail "no alarm raised"
    grep -m1 '^vibid_alarm,' alarms.influx | grep -q '^vibid_alarm,parameter=c2,stand=paper_example1 state="raised"' || fail "first alarm not c2"
    [ "$first" -ge 80000 ] || fail "alarm at sample $first, before the change at 80000 (false alarm)"
    [ "$first" -le 86000 ] || fail "alarm at sample $first: more than 3 s after the change"
    # The last row (20 s after the crack, 40 memories of the RLS) has tracked the new c2:
    # within 1 % of 1.35e6 (its standard error there is 0.3 %, so 1 % is about 3.3 of them;
    # measured +0.08 %), far from the 1.5e6 before the crack.
    [ "$(sed -n '/^time_s,/p' tracks.csv | cut -d, -f7,8)" = "c2,c2_se" ] || fail "tracks columns: $(grep -m1 '^time_s' tracks.csv)"
    c2_after=$(awk -F, 'END { print $7 }' tracks.csv)
    awk -v c="$c2_after" 'BEGIN { exit !(c > 1.35e6 * 0.99 && c < 1.35e6 * 1.01) }' ||
        fail "final c2 = $c2_after, not within 1 % of the changed 1.35e6"
    note "c2 alarm at sample $first (t = $(awk -v i="$first" 'BEGIN { print i / 2000 }') s, change at 40 s); final c2 = $c2_after (truth 1.35e6)"
    ;;
torn_lines)
    # A run killed mid-write (kill -9, a full disk) leaves a torn last line; the next run
    # cuts it off (logged, counted in the status) before appending, so no corrupt row sits
    # mid-file. The torn tails are crafted (where a kill lands is chance): a tracks row, an
    # InfluxDB point and a recorded sample cut mid-line, then a file without any newline.
    $GEN "$STAND" --duration 4 --noise 0.001 --seed 1 --csv cap.csv 2>/dev/null || fail "generator"
    config_csv v.cfg 'outputs = { tracks = { path = "tracks.csv"; }; influx = { path = "tracks.influx"; };
  record = { path = "raw.csv"; }; status = { path = "status"; interval = 0.2; }; };'
    sed -i '/^outputs = { tracks = { path = "tracks.csv"; }; status/d' v.cfg
    timeout 60 "$VIBIDD" -c v.cfg 2> log || fail "first run: $(cat log)"
    good_rows=$(data_rows tracks.csv)
    [ "$good_rows" -eq 40 ] || fail "first run: $good_rows rows, expected 40"
    cp tracks.csv tracks.good; cp tracks.influx influx.good; cp raw.csv raw.good
    printf '3.999,7999,2500' >> tracks.csv           # a row cut mid-number
    printf 'vibid,stand=x c1=2.5e5' >> tracks.influx  # a point cut mid-line
    printf '1.2345,0.000' >> raw.csv                  # a sample cut mid-row
    timeout 60 "$VIBIDD" -c v.cfg 2> log2 || fail "second run: $(cat log2)"
    for f in tracks.csv tracks.influx raw.csv; do
        grep -q "$f: cut off a torn last line of [0-9]* bytes" log2 || fail "no warning for $f: $(cat log2)"
        [ "$(tail -c 1 "$f" | od -An -c | tr -d ' ')" = '\n' ] || fail "$f does not end in a newline"
    done
    [ "$(status_val torn_lines status)" = 3 ] || fail "status torn_lines $(status_val torn_lines status), expected 3"
    # the first run's content is intact, followed directly by the second run's
    head -c "$(stat -c %s tracks.good)" tracks.csv | cmp -s - tracks.good || fail "tracks: the first run's rows changed"
    head -c "$(stat -c %s raw.good)" raw.csv | cmp -s - raw.good || fail "raw.csv: the first run's samples changed"
    # (real rows print t with six decimals: 3.999500,7999,...)
    grep -q '^3.999,7999,2500' tracks.csv && fail "the torn tracks row is still in the file"
    # every data row of the tracks has the header's number of fields
    awk -F, '!/^#/ { if (nf == 0) nf = NF; else if (NF != nf) bad++ } END { exit bad > 0 }' tracks.csv ||
        fail "a tracks row has a different number of fields"
    [ "$(data_rows tracks.csv)" -eq $((2 * good_rows)) ] || fail "tracks rows $(data_rows tracks.csv), expected $((2 * good_rows))"
    # a file that is torn before its first newline is cut to empty (and gets its header)
    printf 'garbage without newline' > tracks.csv
    timeout 60 "$VIBIDD" -c v.cfg 2> log3 || fail "third run: $(cat log3)"
    [ "$(data_rows tracks.csv)" -eq "$good_rows" ] || fail "tracks cut to empty: $(data_rows tracks.csv) rows"
    head -1 tracks.csv | grep -q '^#' || fail "tracks cut to empty: no preamble: $(head -1 tracks.csv)"
    note "$(grep 'torn' log2 | head -1)"
    ;;
reopen_fail)
    # issue 30 item 1: logrotate moved the three file outputs away and a directory stands
    # where the tracks file was; at SIGHUP the tracks cannot be reopened. The InfluxDB file
    # and the recording must be reopened all the same, the tracks retried until the path is a
    # file again, and every row that could not be written counted: rows in both tracks files +
    # tracks_lost_rows = rows; nothing lost from the others; exit status 1 (write errors).
    $GEN "$STAND" --duration 60 --noise 0.001 --seed 12 --csv cap.csv 2>/dev/null || fail "generator"
    config_csv v.cfg 'outputs = { tracks = { path = "tracks.csv"; }; influx = { path = "tracks.influx"; };
  record = { path = "raw.csv"; }; status = { path = "status"; interval = 0.1; }; };'
    sed -i '/^outputs = { tracks = { path = "tracks.csv"; }; status/d' v.cfg
    timeout 90 "$VIBIDD" -c v.cfg --pace --speed 2 2> log &
    pid=$!
    wait_status rows 'v >= 10' 20 || fail "no rows: $(cat log)"
    mv tracks.csv tracks.1
    mv tracks.influx influx.1
    mv raw.csv raw.1
    mkdir tracks.csv
    kill -HUP $pid
    wait_status tracks_lost_rows 'v >= 5' 20 || fail "no lost rows counted: $(grep -v info log)"
    [ "$(status_val outputs_closed)" = 1 ] || fail "outputs_closed $(status_val outputs_closed)"
    [ -f tracks.influx ] || fail "the InfluxDB file was not reopened with the tracks closed"
    [ -f raw.csv ] || fail "the recording was not reopened with the tracks closed"
    grep -q "reopening after SIGHUP: cannot open ./tracks.csv for appending: Is a directory" log ||
        fail "the failure is not logged: $(grep -v info log)"
    # the path a file again: the retry (1 s, 2 s, 4 s ...) opens it without another SIGHUP
    rmdir tracks.csv
    wait_status outputs_closed 'v == 0' 30 || fail "the tracks were not opened again: $(grep -v info log)"
    grep -q "tracks ./tracks.csv is open again" log || fail "no notice: $(grep -v info log)"
    wait_status rows "v >= $(status_val rows) + 5" 20 || fail "no rows after the retry"
    kill -TERM $pid
    wait $pid; rc=$?
    [ $rc -eq 1 ] || fail "exit status $rc with rows lost (expected 1): $(grep -v info log | tail -3)"
    rows=$(status_val rows)
    lost=$(status_val tracks_lost_rows)
    in_files=$(( $(data_rows tracks.1) + $(data_rows tracks.csv) ))
    [ $((in_files + lost)) -eq "$rows" ] || fail "tracks: $in_files rows in the files + $lost lost != $rows rows"
    [ "$(status_val influx_lost_lines)" = 0 ] && [ "$(status_val record_lost_samples)" = 0 ] ||
        fail "lost from the outputs that reopened: $(grep _lost_ status)"
    lines=$(cat influx.1 tracks.influx | grep -c '^vibid,')
    [ "$lines" -eq "$rows" ] || fail "InfluxDB file: $lines lines for $rows rows"
    samples=$(cat raw.1 raw.csv | grep -vc '^#\|^t,')
    [ "$samples" -eq "$(status_val samples)" ] || fail "recording: $samples samples of $(status_val samples)"
    of=$(status_val output_open_failures)
    [ "$of" -ge 1 ] && [ "$(status_val write_errors)" = "$of" ] || fail "output_open_failures $of, write_errors $(status_val write_errors)"
    note "tracks unopenable at SIGHUP: $lost of $rows rows lost and counted, $of failed opens; influx $lines of $rows lines, recording $samples samples: none lost"
    ;;
bad_capture)
    # issue 30 item 9: a CSV that starts with a UTF-8 byte order mark (a spreadsheet's export)
    # replays like the same CSV without it (it said "time_column 't' is not in the header");
    # a capture without one usable line is an error (exit 2), not a run that identified nothing
    $GEN "$STAND" --duration 2 --noise 0.001 --seed 13 --csv plain.csv 2>/dev/null || fail "generator"
    printf '\xef\xbb\xbf' | cat - plain.csv > cap.csv
    config_csv v.cfg ""
    timeout 60 "$VIBIDD" -c v.cfg 2> log || fail "a CSV with a byte order mark: exit $?: $(grep -v info log)"
    [ "$(status_val samples)" = 4000 ] || fail "BOM: $(status_val samples) samples of 4000"
    cp tracks.csv tracks.bom
    rm -f tracks.csv status
    cp plain.csv cap.csv
    timeout 60 "$VIBIDD" -c v.cfg 2> log || fail "plain CSV: exit $?"
    cmp -s tracks.csv tracks.bom || fail "the tracks with and without the byte order mark differ"
    # a wrong column name lists the header's columns
    sed 's/column = "x2"/column = "y2"/' v.cfg > w.cfg
    timeout 60 "$VIBIDD" -c w.cfg 2> log; rc=$?
    [ $rc -eq 2 ] && grep -q "column 'y2' is not in the header of ./cap.csv (its columns: 't', 'x1', 'x2', 's')" log ||
        fail "wrong column: rc $rc $(grep -v info log)"
    # every data line bad: exit 2 with the reason
    { head -1 plain.csv; for i in $(seq 50); do echo "garbage,$i,x,y"; done; } > cap.csv
    rm -f tracks.csv status
    timeout 60 "$VIBIDD" -c v.cfg --rate-check off 2> log; rc=$?
    [ $rc -eq 2 ] || fail "a capture without a usable line: exit $rc: $(grep -v info log | tail -3)"
    grep -q "cap.csv: no usable sample in the whole capture (50 bad lines" log || fail "message: $(grep -v info log | tail -3)"
    note "BOM: the same tracks as without; $(grep -o 'no usable sample[^:]*' log)"
    ;;
check_outputs)
    # --check runs the outputs' start-up checks, so it refuses what the run refuses (and
    # passes what the run accepts): a host name for influx.udp, a missing output
    # directory, a directory where a file should be, an unresolvable UDP host (issue 12,
    # item 7). (A read-only directory is refused by a probe file, not access(); this
    # test runs as root, where only a read-only file system would show it.)
    $GEN "$STAND" --duration 1 --noise 0.001 --seed 1 --csv cap.csv 2>/dev/null || fail "generator"
    mkdir adir
    n=0
    # each case: the outputs group's content | expected exit status | expected message
    for case in 'tracks = { path = "tracks.csv"; }; influx = { udp = "localhost:8089"; };|0|' \
                'tracks = { path = "tracks.csv"; }; influx = { udp = "no-such-host.invalid:8089"; };|2|outputs.influx.udp: '"'"'no-such-host.invalid'"'"' does not resolve to an IPv4 address' \
                'tracks = { path = "nodir/tracks.csv"; };|2|outputs.tracks.path ./nodir/tracks.csv: the directory ./nodir: No such file or directory' \
                'tracks = { path = "adir"; };|2|outputs.tracks.path ./adir: not a regular file' \
                'tracks = { path = "tracks.csv"; }; record = { path = "cap.csv/raw.csv"; };|2|outputs.record.path ./cap.csv/raw.csv: ./cap.csv is not a directory' \
                'tracks = { path = "tracks.csv"; }; status = { path = "nodir/status"; };|2|outputs.status.path ./nodir/status: the directory ./nodir'; do
        outs=${case%%|*} rest=${case#*|}
        want_rc=${rest%%|*} want=${rest#*|}
        n=$((n + 1))
        config_csv v.cfg ""
        sed -i "s|^outputs = .*|outputs = { $outs };|" v.cfg
        grep -qF "$outs" v.cfg || fail "case $n: configuration not edited"
        for mode in check run; do
            rm -f tracks.csv
            # shellcheck disable=SC2046
            timeout 20 "$VIBIDD" -c v.cfg $([ $mode = check ] && echo --check) > out 2> log; rc=$?
            [ $rc -eq "$want_rc" ] || fail "case $n ($outs, $mode): exit $rc, expected $want_rc: $(grep -v info log)"
            [ -z "$want" ] || grep -qF "$want" log || fail "case $n ($outs, $mode): message: $(grep -v info log)"
        done
    done
    ls -a | grep -q '^.vibidd-check' && fail "a probe file was left behind"
    note "$(grep error log)"
    ;;
full_disk)
    # A full disk (a 128 KiB tmpfs mounted by the test: this needs root, as the VM tests
    # do) under the tracks, the raw recording and the status file (issue 12, item 5):
    # every output's loss is logged (the recording fills the disk first; the tracks'
    # failure must be logged too, not hidden behind it), the status file shows the write
    # errors (overwritten in place when its .tmp cannot be written), no .tmp is left
    # behind, and the exit status is 1.
    mkdir full
    mount -t tmpfs -o size=128k tmpfs full || fail "cannot mount a tmpfs (this test needs root)"
    trap 'umount "$W/full" 2>/dev/null; rm -rf "$W"' EXIT
    $GEN "$STAND" --duration 20 --noise 0.001 --seed 1 --csv cap.csv 2>/dev/null || fail "generator"
    config_csv v.cfg ""
    sed -i 's|^outputs = .*|outputs = { tracks = { path = "full/tracks.csv"; }; record = { path = "full/raw.csv"; }; status = { path = "full/status"; interval = 0.05; }; };|' v.cfg
    timeout 60 "$VIBIDD" -c v.cfg 2> log; rc=$?
    [ $rc -eq 1 ] || fail "exit status $rc, expected 1 (write errors): $(grep -v info log | tail -3)"
    grep -q "writing raw recording ./full/raw.csv failed: No space left on device" log || fail "recording loss not logged: $(grep error log | head -3)"
    grep -q "writing tracks ./full/tracks.csv failed: No space left on device" log || fail "tracks loss not logged: $(grep error log | head -3)"
    ls full | grep -q '\.tmp$' && fail "a .tmp was left behind: $(ls -la full)"
    we=$(status_val write_errors full/status)
    [ -n "$we" ] && [ "$we" -gt 0 ] || fail "status write_errors '$we' (status: $(head -3 full/status))"
    [ "$(status_val state full/status)" = stopped ] || fail "status state $(status_val state full/status)"
    note "status: write_errors=$we; $(grep -c 'failed: No space' log) error lines logged"
    umount full
    ;;
slow_peer)
    # A Modbus peer that drips its answers one byte per 0.45 s (each byte within the 0.5 s
    # response timeout): vibidd keeps running (a peer is never a reason to exit), counts
    # the timeouts, and SIGTERM ends it within 2 s (before: ignored for more than 150 s,
    # no fault counted, the watchdog stopped). Issue 12, item 2. The peer serves the
    # drivers' test FIFO (3 channels at 100 Hz), mapped here onto a 2-DOF stand.
    [ -x "${VIBID_PYTHON:-}" ] || fail "VIBID_PYTHON='${VIBID_PYTHON:-}' is not an executable venv interpreter"
    port=$("$VIBID_PYTHON" -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
    "$VIBID_PYTHON" "$SRC/tests/drivers/modbus_slow_server.py" --port "$port" --drip 0.45 --max-time 30 > srv.out 2>&1 &
    srv=$!
    for _ in $(seq 50); do grep -q READY srv.out && break; sleep 0.1; done
    grep -q READY srv.out || fail "slow server did not start: $(cat srv.out)"
    sed 's/sample_rate = 2000.0;/sample_rate = 100.0;/' "$STAND" > stand100.cfg
    cat > v.cfg <<EOF
stand = "stand100.cfg";
source = {
  kind = "modbus"; url = "tcp://127.0.0.1:$port"; mode = "fifo"; fifo_base = 1000; poll_period = 0.02;
  response_timeout = 0.5; backoff_initial = 0.05; backoff_max = 0.4;
  registers = (
    { name = "a"; address = 0;  type = "FLOAT32"; byte_order = "ABCD"; },
    { name = "b"; address = 2;  type = "INT16"; scale = 0.001; },
    { name = "c"; address = 10; type = "FLOAT32"; byte_order = "CDAB"; }
  );
  channels = (
    { name = "x1"; quantity = "displacement"; node = 0; unit = "m"; register = "a"; },
    { name = "x2"; quantity = "displacement"; node = 1; unit = "m"; register = "b"; },
    { name = "s";  quantity = "base_displacement"; node = 0; unit = "m"; register = "c"; }
  );
};
outputs = { tracks = { path = "tracks.csv"; }; status = { path = "status"; interval = 0.2; }; };
EOF
    "$VIBIDD" -c v.cfg 2> log &
    pid=$!
    sleep 4
    if ! kill -0 $pid 2>/dev/null; then
        wait $pid
        fail "vibidd ended by itself (exit $?): $(grep -v info log | tail -3)"
    fi
    t0=$(date +%s%N)
    kill -TERM $pid
    for _ in $(seq 100); do kill -0 $pid 2>/dev/null || break; sleep 0.05; done
    t1=$(date +%s%N)
    if kill -0 $pid 2>/dev/null; then
        kill -9 $pid
        fail "SIGTERM ignored for 5 s"
    fi
    wait $pid
    kill $srv 2>/dev/null
    wait $srv 2>/dev/null
    ms=$(( (t1 - t0) / 1000000 ))
    [ "$ms" -le 2000 ] || fail "SIGTERM took $ms ms"
    to=$(status_val source_timeouts status)
    { [ -n "$to" ] && [ "$to" -ge 3 ]; } || fail "source_timeouts '$to' (status: $(grep source_ status | tr '\n' ' '))"
    note "SIGTERM honoured in $ms ms; source_timeouts=$to, source_link_losses=$(status_val source_link_losses status)"
    ;;
same_file)
    # Outputs that are the same file, or an output that is an input, are configuration
    # errors (exit 2, before anything is opened), in the run and in --check; the file
    # that would have been destroyed is left as it was (issue 12, item 6).
    printf 't,x1,x2,s\n0,0,0,0\n' > cap.csv
    cp cap.csv cap.orig
    echo "previous tracks" > tracks.csv
    n=0
    for case in "--status tracks.csv|outputs.tracks.path (./tracks.csv) and outputs.status.path (tracks.csv) are the same file: one output would overwrite the other" \
                "--status ./tracks.csv|outputs.tracks.path (./tracks.csv) and outputs.status.path (./tracks.csv) are the same file" \
                "--record cap.csv|outputs.record.path (cap.csv) and source.file (./cap.csv) are the same file: writing it would destroy an input" \
                "--record link.csv|outputs.record.path (link.csv) and source.file (./cap.csv)" \
                "--tracks v.cfg|outputs.tracks.path (v.cfg) and the configuration file (v.cfg)" \
                "--record capture2.csv --replay capture2.csv|outputs.record.path (capture2.csv) and the replayed capture (--replay) (capture2.csv)"; do
        args=${case%%|*} want=${case#*|}
        n=$((n + 1))
        config_csv v.cfg ""
        ln -sf cap.csv link.csv
        cp cap.csv capture2.csv
        for mode in run check; do
            # shellcheck disable=SC2086
            timeout 10 "$VIBIDD" -c v.cfg $args $([ $mode = check ] && echo --check) > out 2> log; rc=$?
            [ $rc -eq 2 ] || fail "case $n ($args, $mode): exit $rc, expected 2: $(cat log)"
            grep -qF "$want" log || fail "case $n ($args, $mode): message: $(cat log)"
        done
        cmp -s cap.csv cap.orig || fail "case $n: the capture was modified"
        [ "$(cat tracks.csv)" = "previous tracks" ] || fail "case $n: the tracks file was modified"
    done
    note "$(cat log)"
    ;;
rate_mismatch)
    # "Data that do not fit the stand are refused": captures made at 1 kHz (a copy of the
    # stand with sample_rate 1000) replayed with the stand's 2 kHz. Before the check (and
    # with --rate-check off) both ran to exit 0: the CSV with every row a one-sample gap and
    # no estimate at all (99 rows flagged GE), the candump log with d = 600 instead of 300
    # N s/m and c1, c2 four times the truth; a 2 kHz capture with a 1 kHz stand gave d = 150,
    # c1, c2 a quarter. Now: exit 2 before any output exists, the message names both rates;
    # the same for candump (counter and trigger), for --check, and the other way round.
    rate_stand 1000.0 stand1k.cfg
    $GEN stand1k.cfg --duration 10 --noise 0.001 --seed 11 --csv cap.csv --candump cap.log 2>/dev/null ||
        fail "generator"
    want="is 50.0 % off the stand's sample_rate 2000 Hz ($STAND): fix stand.sample_rate or the capture"
    config_csv v.cfg ""
    timeout 30 "$VIBIDD" -c v.cfg 2> log; rc=$?
    [ $rc -eq 2 ] || fail "CSV at half rate: exit $rc, expected 2: $(cat log)"
    grep -qF "cap.csv: sample rate 1000.0 Hz (from the time column 't', samples 0..4001) $want" log ||
        fail "CSV message: $(cat log)"
    [ ! -e tracks.csv ] && [ ! -e status ] || fail "CSV at half rate: outputs were opened"
    note "$(grep error log)"
    timeout 30 "$VIBIDD" -c v.cfg --check > printout 2> log; rc=$?
    [ $rc -eq 2 ] || fail "--check on the CSV at half rate: exit $rc, expected 2: $(cat log)"
    grep -qF "cap.csv: sample rate 1000.0 Hz (from the time column 't', samples 0..4001) $want" log ||
        fail "--check message: $(cat log)"
    [ ! -s printout ] || fail "--check printed a configuration although it failed"
    config_candump c.cfg ""
    timeout 30 "$VIBIDD" -c c.cfg 2> log; rc=$?
    [ $rc -eq 2 ] || fail "candump (counter) at half rate: exit $rc: $(cat log)"
    grep -qF "cap.log: sample rate 1000.0 Hz (from the candump timestamps, samples 0..4001) $want" log ||
        fail "candump (counter) message: $(cat log)"
    note "$(grep error log)"
    sed 's/counter = "Counter";/trigger = "Sample_A";/' c.cfg > t.cfg
    grep -q 'trigger = "Sample_A"' t.cfg || fail "test setup: trigger not set"
    timeout 30 "$VIBIDD" -c t.cfg 2> log; rc=$?
    [ $rc -eq 2 ] || fail "candump (trigger) at half rate: exit $rc: $(cat log)"
    grep -qF "cap.log: sample rate 1000.0 Hz (from the candump timestamps, samples 0..4001) $want" log ||
        fail "candump (trigger) message: $(cat log)"
    timeout 30 "$VIBIDD" -c t.cfg --check > printout 2> log; rc=$?
    [ $rc -eq 2 ] && grep -qF "$want" log || fail "--check on the candump log: exit $rc: $(cat log)"
    [ ! -e tracks.csv ] && [ ! -e tracks.influx ] || fail "candump at half rate: outputs were opened"
    # the other way round: a 1 kHz stand with a 2 kHz capture (twice the damping before)
    $GEN "$STAND" --duration 5 --seed 12 --csv cap2k.csv 2>/dev/null || fail "generator"
    sed "s|^stand = \"$STAND\";|stand = \"$W/stand1k.cfg\";|" v.cfg > slow.cfg
    grep -q 'stand1k.cfg' slow.cfg || fail "test setup: stand not replaced"
    timeout 30 "$VIBIDD" -c slow.cfg --replay cap2k.csv 2> log; rc=$?
    [ $rc -eq 2 ] || fail "2 kHz capture, 1 kHz stand: exit $rc: $(cat log)"
    grep -qF "cap2k.csv: sample rate 2000.0 Hz (from the time column 't', samples 0..8001) is 100.0 % off the stand's sample_rate 1000 Hz ($W/stand1k.cfg)" log ||
        fail "2 kHz capture message: $(cat log)"
    # --rate-check warn: a warning and the run goes on; off: not a word
    timeout 30 "$VIBIDD" -c v.cfg --rate-check warn 2> log || fail "--rate-check warn: exit $?: $(cat log)"
    grep -qF "$want (--rate-check warn: going on)" log || fail "--rate-check warn message: $(cat log)"
    [ -s tracks.csv ] || fail "--rate-check warn: no tracks"
    rm -f tracks.csv status
    timeout 30 "$VIBIDD" -c v.cfg --rate-check off 2> log || fail "--rate-check off: exit $?: $(cat log)"
    ! grep -q "sample rate" log || fail "--rate-check off still checked: $(cat log)"
    timeout 10 "$VIBIDD" -c v.cfg --rate-check maybe 2> log; rc=$?
    [ $rc -eq 2 ] && grep -q "expected error, warn or off" log || fail "bad --rate-check accepted: rc $rc"
    ;;
rate_tolerance)
    # 0.5 % off (a capture at 2010 Hz, the stand at 2000 Hz) is accepted, for CSV, candump
    # and --check; 1.5 % off is refused. Accuracy is not asserted (the estimates carry the
    # 0.5 % time-scale error by design).
    rate_stand 2010.0 stand2010.cfg
    $GEN stand2010.cfg --duration 5 --seed 13 --csv cap.csv --candump cap.log 2>/dev/null || fail "generator"
    config_csv v.cfg ""
    timeout 30 "$VIBIDD" -c v.cfg 2> log || fail "CSV 0.5 % off: exit $?: $(cat log)"
    grep -qF "cap.csv: sample rate 2010.0 Hz (from the time column 't', samples 0..4020) fits the stand's sample_rate 2000 Hz ($STAND): +0.50 %" log ||
        fail "CSV 0.5 % off: message: $(cat log)"
    rows=$(data_rows tracks.csv)
    [ "$rows" -eq 50 ] || fail "CSV 0.5 % off: expected 50 rows (10050 samples / 200), got $rows"
    note "$(grep 'fits' log)"
    # --check: the outcome is the printout's last line, a comment (the printout stays a configuration)
    timeout 30 "$VIBIDD" -c v.cfg --check > printout 2> log || fail "--check 0.5 % off: exit $?: $(cat log)"
    tail -n 1 printout | grep -qF "# ./cap.csv: sample rate 2010.0 Hz (from the time column 't', samples 0..4020) fits the stand's sample_rate 2000 Hz" ||
        fail "--check 0.5 % off: last line $(tail -n 1 printout); log $(cat log)"
    [ ! -s log ] || fail "--check 0.5 % off wrote to stderr: $(cat log)"
    cp printout again.cfg
    timeout 30 "$VIBIDD" -c again.cfg --check > printout2 2> log || fail "the printout does not read back: $(cat log)"
    tail -n 1 printout2 | grep -qF "fits the stand's sample_rate 2000 Hz" || fail "read back: $(tail -n 1 printout2)"
    config_candump c.cfg ""
    timeout 30 "$VIBIDD" -c c.cfg 2> log || fail "candump 0.5 % off: exit $?: $(cat log)"
    grep -qF "cap.log: sample rate 2010.0 Hz (from the candump timestamps, samples 0..4020) fits" log ||
        fail "candump 0.5 % off: message: $(cat log)"
    rate_stand 2030.0 stand2030.cfg
    $GEN stand2030.cfg --duration 5 --seed 14 --csv cap15.csv 2>/dev/null || fail "generator"
    timeout 30 "$VIBIDD" -c v.cfg --replay cap15.csv 2> log; rc=$?
    [ $rc -eq 2 ] && grep -qF "cap15.csv: sample rate 2030.0 Hz (from the time column 't', samples 0..8121) is 1.5 % off" log ||
        fail "1.5 % off: exit $rc: $(cat log)"
    note "$(grep error log)"
    ;;
modbus_loopback)
    # issue 7 test 1: vibid-sim serves example 1 over Modbus TCP on loopback at 2 kHz,
    # vibidd polls the FIFO; final estimates within 1 % of the truth. The raw recording of
    # this live run, replayed, must give the same tracks bit for bit.
    start_sim --duration 30
    config_modbus v.cfg "$PORT"
    timeout 30 "$VIBIDD" -c v.cfg 2> log &
    pid=$!
    sleep 8
    kill -TERM $pid
    wait $pid || fail "vibidd exit status $?: $(cat log)"
    kill $SIMPID 2>/dev/null; wait $SIMPID 2>/dev/null
    samples=$(status_val samples status)
    note "live: $samples samples, gaps $(status_val gaps status), failed polls $(status_val source_failed_polls status), latency p50 $(status_val latency_us_p50 status) us p99 $(status_val latency_us_p99 status) us"
    [ "$samples" -gt 12000 ] || fail "too few samples ($samples) in 8 s at 2 kHz"
    [ "$(status_val gaps status)" = 0 ] || fail "gaps on a clean loopback"
    final=$(check_final tracks.csv 1.0) || exit 1; note "$final"
    timeout 60 "$VIBIDD" -c v.cfg --replay raw.csv --tracks replay.csv --record "" --status "" 2> log2 \
        || fail "replay: $(cat log2)"
    cmp tracks.csv replay.csv || fail "replay of the live recording differs from the live tracks"
    note "replay of the live recording: identical tracks ($(data_rows tracks.csv) rows)"
    ;;
modbus_restart)
    # issue 7 test 4: the server stops serving at 3 s and comes back at 4.5 s (new FIFO
    # session); the daemon reconnects, records the gap, continues and converges.
    start_sim --duration 30 --stop-at 3 --resume-at 4.5
    config_modbus v.cfg "$PORT"
    timeout 30 "$VIBIDD" -c v.cfg 2> log &
    pid=$!
    sleep 9
    kill -TERM $pid
    wait $pid || fail "vibidd exit status $?: $(cat log)"
    kill $SIMPID 2>/dev/null; wait $SIMPID 2>/dev/null
    note "link losses $(status_val source_link_losses status), reconnects $(status_val source_reconnects status), gaps $(status_val gaps status) ($(status_val missing_samples status) samples), faults $(status_val faults status)"
    [ "$(status_val source_link_losses status)" -ge 1 ] || fail "no link loss recorded"
    [ "$(status_val source_reconnects status)" -ge 1 ] || fail "no reconnect"
    [ "$(status_val gaps status)" -ge 1 ] || fail "no gap recorded"
    grep -q ',G[A-Z]*$' tracks.csv || fail "gap not flagged in the tracks"
    final=$(check_final tracks.csv 1.0) || exit 1; note "$final"
    ;;
sim_can_faults)
    # issue 7 test 4: frames dropped (1 %) and duplicated (1 %) by vibid-sim in its candump
    # output (its own DBC), replayed: every sample accounted for, faults reported, final
    # estimates within 1 %. Corrupted log lines are tested in gaps_faults.
    [ -x "$SIM" ] || fail "vibid-sim not built"
    "$SIM" -c "$STAND" -s "$SIMCFG" --duration 20 --candump cap.log --epoch 1700000000 --drop 0.01 \
        --duplicate 0.01 --fast -q 2> sim.err || fail "vibid-sim: $(cat sim.err)"
    config_candump v.cfg ""
    sed -i "s#dbc = \"$DBC\"; counter = \"Counter\";#dbc = \"$SRC/sim/paper_example1.dbc\"; counter = \"SampleCounter\";#;
            s/signal = \"X1\"; message = \"Sample_A\"/signal = \"x1\"/; s/signal = \"X2\"; message = \"Sample_B\"/signal = \"x2\"/;
            s/signal = \"S\"; message = \"Sample_C\"/signal = \"s\"/" v.cfg
    timeout 60 "$VIBIDD" -c v.cfg 2> log || fail "vibidd: $(cat log)"
    samples=$(status_val samples status); missing=$(status_val missing_samples status)
    note "samples $samples, gaps $(status_val gaps status), missing $missing, faults $(status_val faults status)"
    [ $((samples + missing)) -eq 40000 ] || fail "samples + missing = $((samples + missing)) != 40000"
    [ "$(status_val faults status)" -gt 100 ] || fail "duplicates not reported as faults"
    final=$(check_final tracks.csv 1.0) || exit 1; note "$final"
    # The same plus corrupted frames (0.1 %: one random payload bit flipped). A flipped
    # bit in the 16-bit SampleCounter used to declare a jump of up to 32767 samples
    # (before the fix: samples + missing = 121240, 41818 faults); the CAN assembler now
    # judges a jump against the frame times and the nominal period
    # (drivers/include/vibid_drivers/can_assembler.h) and reports a "corrupt" fault.
    # Only counts are asserted for this run: a flipped bit in a float value (e.g. its
    # exponent) cannot be detected without a checksum in the frame and ruins a
    # least-squares estimate, so no accuracy is claimed.
    "$SIM" -c "$STAND" -s "$SIMCFG" --duration 20 --candump cap.log --epoch 1700000000 --drop 0.01 \
        --duplicate 0.01 --corrupt 0.001 --fast 2> sim.err || fail "vibid-sim: $(cat sim.err)"
    corrupted=$(sed -n 's/.*CAN frames: .* \([0-9]*\) corrupted$/\1/p' sim.err)
    [ -n "$corrupted" ] && [ "$corrupted" -gt 0 ] || fail "vibid-sim did not report corrupted frames: $(cat sim.err)"
    rm -f status tracks.csv tracks.influx
    timeout 60 "$VIBIDD" -c v.cfg 2> log || fail "vibidd (corrupt run): $(cat log)"
    samples=$(status_val samples status); missing=$(status_val missing_samples status)
    corrupt=$(status_val faults_corrupt status)
    note "corrupt run: $(grep 'CAN frames' sim.err)"
    note "corrupt run: samples $samples, gaps $(status_val gaps status), missing $missing," \
         "faults $(status_val faults status) (corrupt counters $corrupt, duplicates" \
         "$(status_val faults_duplicate status), late $(status_val faults_late status))"
    # every sample index accounted for exactly once: no phantom jump
    [ $((samples + missing)) -eq 40000 ] || fail "corrupt run: samples + missing = $((samples + missing)) != 40000"
    # a quarter of the flipped bits land in the counter, most far beyond the 16-sample
    # slack: at least one corrupt-counter fault, never more than frames corrupted
    [ -n "$corrupt" ] && [ "$corrupt" -ge 1 ] && [ "$corrupt" -le "$corrupted" ] ||
        fail "faults_corrupt = '$corrupt', want 1..$corrupted (frames corrupted by vibid-sim)"
    # the gaps stay those of dropped frames and corrupt counters: missing samples at most
    # dropped + corrupted frames, plus 7 per corrupted frame (a flip in counter bits 0..2
    # within the slack can still open a later sample, skipping at most 7)
    dropped=$(sed -n 's/.*generated, \([0-9]*\) dropped.*/\1/p' sim.err)
    [ "$missing" -le $((dropped + 8 * corrupted)) ] ||
        fail "corrupt run: $missing missing samples > dropped $dropped + 8 x corrupted $corrupted"
    ;;
sim_diagnostics)
    # issue 7 test 5 with the simulator: c2 -10 % at 40 s (sim_crack.cfg), CSV capture.
    [ -x "$SIM" ] || fail "vibid-sim not built"
    "$SIM" -c "$STAND" -s "$SRC/tests/daemon/data/sim_crack.cfg" --duration 60 --csv cap.csv --epoch 1700000000 \
        --fast -q 2> sim.err || fail "vibid-sim: $(cat sim.err)"
    config_csv v.cfg 'alarms = { test = "threshold"; threshold = 5.0; min_relative = 0.03; hold = 1.0; learn_start = 10.0;
  learn_duration = 15.0; };'
    sed -i 's/method = "rls";/method = "rls"; forgetting = 0.999;/;
            s/tracks = { path = "tracks.csv"; };/tracks = { path = "tracks.csv"; }; influx = { path = "alarms.influx"; };/' v.cfg
    timeout 60 "$VIBIDD" -c v.cfg 2> log || fail "vibidd: $(cat log)"
    first=$(grep -m1 '^vibid_alarm,' alarms.influx | sed 's/.*index=\([0-9]*\)i.*/\1/')
    [ -n "$first" ] || fail "no alarm raised"
    grep -m1 '^vibid_alarm,' alarms.influx | grep -q '^vibid_alarm,parameter=c2,stand=paper_example1 state="raised"' || fail "first alarm not c2: $(head -1 alarms.influx)"
    [ "$first" -ge 80000 ] || fail "alarm at sample $first, before the change at 80000 (false alarm)"
    [ "$first" -le 86000 ] || fail "alarm at sample $first: more than 3 s after the change"
    note "c2 alarm at sample $first (change at sample 80000); $(grep -c 'state="raised"' alarms.influx) alarm(s) raised in total"
    ;;
implausible)
    # The issue "physically impossible estimates are never plain rows": ZOH + batch LS on
    # noisy data from vibid-sim (example 1 with the nominal values given, so that the zeta
    # rule is on; smooth triangle base 1 mm / 5 Hz; a row every 100
    # samples; the pre-filter, which hides the problem at these noise levels, is off
    # explicitly). Measured: with 1 % noise (SNR 40 dB on x1, x2) over 2 s every row has
    # c2 < 0 (about -1e8 N/m), f1 = 0 Hz, zeta1 = 1; with 0.3 % (50 dB) over 4 s c2 < 0
    # in the first row, then plausible rows, then c2 < 0 again (at 55 dB and cleaner every
    # row is plausible). Checked on the CSV with the header's rules: every row with an
    # impossible value carries P and every P row has one; one warning per episode of P
    # rows and one notice per end; implausible_rows in the status; no alarm event on a P
    # row (every row impossible: no alarm at all, though the P rows are far enough off to
    # raise one, and a warning that a baseline to be learned was not; mixed: an alarm
    # raised on a plausible row, none on P rows).
    [ -x "$SIM" ] || fail "vibid-sim not built"
    sed -e 's/name = "paper_example1";/name = "paper_example1_zoh";/' \
        -e 's/^  discretization = .*/  discretization = "zoh";/' \
        -e 's/unknown = true; true_value = \([0-9.e]*\);/unknown = true; value = \1; true_value = \1;/' \
        "$STAND" > stand_zoh.cfg
    [ "$(grep -c 'value = [0-9.e]*; true_value' stand_zoh.cfg)" = 3 ] && grep -q '"zoh"' stand_zoh.cfg ||
        fail "test setup: stand_zoh.cfg not made: $(cat stand_zoh.cfg)"
    # impossible_rows TRACKS prints "rows impossible flagged unflagged p_without episodes
    # ends" by the header's rules (masses known here; c1, d, c2 > 0; modes > 0 Hz and
    # < 1000 Hz; 0 <= zeta < 1, both nominal modes being underdamped, zeta 0.065 / 0.044);
    # rows flagged E (no estimate) are left out, as the daemon leaves them out of episodes
    impossible_rows() {
        awk -F, 'function bad(v) { return v ~ /nan|inf/ }
        /^#/ { next }
        !hdr { for (i = 1; i <= NF; i++) col[$i] = i; hdr = 1; next }
        {
            fl = $col["flags"]
            if (fl ~ /E/) next
            imp = 0
            if (bad($col["c1"]) || bad($col["d"]) || bad($col["c2"])) imp = 1
            else if ($col["c1"] + 0 <= 0 || $col["d"] + 0 <= 0 || $col["c2"] + 0 <= 0) imp = 1
            for (m = 1; m <= 2; m++) {
                f = $col["f" m "_hz"]; z = $col["zeta" m]
                if (bad(f) || bad(z) || f + 0 <= 0 || f + 0 >= 1000 || z + 0 < 0 || z + 0 >= 1) imp = 1
            }
            p = (fl ~ /P/)
            rows++; nimp += imp
            if (imp && p) fi++
            if (imp && !p) { ui++; print "unflagged impossible row: " $0 > "/dev/stderr" }
            if (!imp && p) { fp++; print "P on a plausible row: " $0 > "/dev/stderr" }
            if (p && !prev) ep++
            if (!p && prev) ends++
            prev = p
        }
        END { printf "%d %d %d %d %d %d %d\n", rows, nimp, fi, ui, fp, ep, ends }' "$1"
    }
    # alarm_on_p_rows TRACKS INFLUX: the number of alarm events whose index is a P row
    alarm_on_p_rows() {
        awk -F, 'FNR == NR { if ($1 !~ /^#/ && $NF ~ /P/) p[$2] = 1; next }
                 /^vibid_alarm,/ { if (match($0, /index=[0-9]+i/)) { i = substr($0, RSTART + 6, RLENGTH - 7); if (i in p) n++ } }
                 END { print n + 0 }' "$1" "$2"
    }
    # out_p_rows TRACKS: P rows on which a parameter is "out" by the alarm rule (z > 5 and
    # 2 %, baselines 2.5e5, 300, 1.5e6): what would raise an alarm if P rows counted
    out_p_rows() {
        awk -F, '/^#/ { next }
        !hdr { for (i = 1; i <= NF; i++) col[$i] = i; hdr = 1; next }
        $col["flags"] ~ /P/ {
            split("c1 d c2", nm, " "); split("2.5e5 300 1.5e6", bl, " "); o = 0
            for (k = 1; k <= 3; k++) {
                v = $col[nm[k]] + 0; se = $col[nm[k] "_se"] + 0; b = bl[k] + 0
                dev = v > b ? v - b : b - v
                if (se > 0 && dev / se > 5 && dev > 0.02 * b) o = 1
            }
            n += o
        }
        END { print n + 0 }' "$1"
    }
    run_case() { # NAME SNR_DB DURATION ALARMS
        printf '%s\n' 'simulation = {' '  seed = 1;' '  hold = "smooth";' \
            '  excitation = ( { target = "base"; kind = "triangle"; amplitude = 1.0e-3; frequency = 5.0; } );' \
            "  noise = ( { channel = \"x1\"; snr_db = $2; }, { channel = \"x2\"; snr_db = $2; } );" '};' > sim_$1.cfg
        "$SIM" -c stand_zoh.cfg -s sim_$1.cfg --duration "$3" --csv cap.csv --epoch 1700000000 --fast -q 2> sim.err ||
            fail "vibid-sim: $(cat sim.err)"
        config_csv $1.cfg "$4"
        sed -i -e 's|^stand = .*|stand = "stand_zoh.cfg";|' \
               -e 's|^estimator = .*|estimator = { method = "ls"; prefilter_hz = 0.0; decimation = 100; };|' \
               -e 's|tracks = { path = "tracks.csv"; };|tracks = { path = "tracks.csv"; }; influx = { path = "tracks.influx"; };|' \
               $1.cfg
        grep -q 'method = "ls"' $1.cfg && grep -q 'stand_zoh.cfg' $1.cfg && grep -q 'tracks.influx' $1.cfg ||
            fail "test setup: $1.cfg not changed"
        rm -f tracks.csv tracks.influx status
        timeout 60 "$VIBIDD" -c $1.cfg 2> log_$1 || fail "vibidd ($1): exit $? $(cat log_$1)"
        cp tracks.csv tracks_$1.csv
        read -r rows nimp fi ui fp ep ends < <(impossible_rows tracks.csv)
        warnings=$(grep -c 'physically impossible estimate at sample' log_$1)
        notices=$(grep -c 'estimates physically plausible again at sample' log_$1)
        on_p=$(alarm_on_p_rows tracks.csv tracks.influx)
        alarms=$(grep -c '^vibid_alarm,' tracks.influx)
        would=$(out_p_rows tracks.csv)
        note "$1 (SNR $2 dB, $3 s): $rows rows, $nimp with impossible values ($fi flagged P, $ui not)," \
             "$fp P rows without; $ep episodes, $ends ends; log: $warnings warnings, $notices notices;" \
             "status implausible_rows=$(status_val implausible_rows status); alarm events $alarms ($on_p on P rows;" \
             "$would P rows out by the alarm rule)"
        note "$1: $(grep -m1 'physically impossible estimate' log_$1)"
        [ "$rows" -gt 0 ] || fail "$1: no rows"
        [ "$nimp" -gt 0 ] || fail "$1: no row with an impossible value: the configuration no longer reproduces the issue"
        [ "$ui" -eq 0 ] || fail "$1: $ui rows with impossible values are not flagged P"
        [ "$fp" -eq 0 ] || fail "$1: $fp rows flagged P without an impossible value"
        [ "$warnings" -eq "$ep" ] || fail "$1: $warnings warnings for $ep episodes"
        [ "$notices" -eq "$ends" ] || fail "$1: $notices notices for $ends episode ends"
        [ "$(status_val implausible_rows status)" = "$fi" ] || fail "$1: status implausible_rows != $fi"
        [ "$on_p" -eq 0 ] || fail "$1: $on_p alarm events on rows flagged P"
        grep -q 'flags="G\?P' tracks.influx || fail "$1: P not in the InfluxDB flags"
    }
    # given baselines (the truth) with hold 0, so that any row counted would raise at once;
    # "all": c1's baseline is to be learned over 0..1 s, where every row is P
    given='{ name = "d"; baseline = 300.0; }, { name = "c2"; baseline = 1.5e6; } ); };'
    run_case all 40 2 "alarms = { test = \"threshold\"; threshold = 5.0; min_relative = 0.02; hold = 0.0; learn_start = 0.0;
  learn_duration = 1.0; parameters = ( { name = \"c1\"; }, $given"
    [ "$nimp" -eq "$rows" ] || fail "all: expected every row impossible at 1 % noise, $nimp of $rows"
    [ "$would" -gt 0 ] || fail "all: no P row would raise an alarm: the alarm check below proves nothing"
    [ "$alarms" -eq 0 ] || fail "all: $alarms alarm events although every row is flagged P"
    grep -q 'c2 = -[0-9.e+]* N/m <= 0 (stiffness must be positive)' log_all || fail "all: the warning does not name c2"
    grep -q 'alarm baseline of c1 not learned: no usable estimate' log_all ||
        fail "all: no warning that c1's baseline could not be learned"
    run_case mixed 50 4 "alarms = { test = \"threshold\"; threshold = 5.0; min_relative = 0.02; hold = 0.0;
  parameters = ( { name = \"c1\"; baseline = 2.5e5; }, $given"
    [ "$ep" -ge 2 ] && [ "$ends" -ge 1 ] ||
        fail "mixed: expected P episodes interrupted by plausible rows, got $ep episodes and $ends ends"
    [ "$alarms" -ge 1 ] || fail "mixed: no alarm event at all (plausible rows far from the truth should raise one)"
    ;;
outlier)
    # Issue 30, item 2: one glitch sample (x1 = 1.0, 1e3, 1e300 in a capture of millimetre
    # motions) used to make every later row P/U for the rest of the run, unnoticed. Now the
    # outlier test (vibid/outlier.h) takes it out before the estimator, which sees a gap:
    # the tracks must equal, bit for bit, those of the same capture with that value
    # replaced by NaN (which the CSV source turns into a one-sample gap); the row covering
    # it is flagged O instead of G (gap_samples 0 instead of 1); outlier_samples = 1,
    # nonfinite_samples = 0; the raw recording keeps the value as received, and replaying
    # the recording gives the same tracks again. Without the test (outlier_threshold = 0)
    # the same capture gives P, U or E on every later row (the failure this case guards).
    # The capture: vibid-sim, example 1, the smooth 1 mm / 5 Hz triangle with 60 dB
    # noise, 10 s; the automatic estimator (the default); the glitch at sample 8000 (4 s).
    [ -x "$SIM" ] || fail "vibid-sim not built"
    "$SIM" -c "$STAND" -s "$SIMCFG" --duration 10 --csv cap.csv -q || fail "vibid-sim"
    [ "$(head -1 cap.csv)" = "t,s,x1,x2" ] || fail "test setup: columns $(head -1 cap.csv)"
    # glitched NAME VALUE: cap.csv with x1 of sample 8000 (line 8002) replaced
    glitched() { awk -F, -v OFS=, -v g="$2" 'NR == 8002 { $3 = g } { print }' cap.csv > "$1"; }
    # run NAME CAPTURE EXTRA: vibidd on CAPTURE; tracks NAME.csv, status NAME.status, raw NAME.raw.csv
    run() {
        sed -e "s|file = \"cap.csv\"|file = \"$2\"|" -e "s|tracks.csv|$1.csv|" -e "s|path = \"status\"|path = \"$1.status\"|" \
            -e 's|^estimator = .*$||' v0.cfg > "$1.cfg"
        sed -i "s|^outputs = { |outputs = { record = { path = \"$1.raw.csv\"; }; |" "$1.cfg"
        printf '%s\n' "$3" >> "$1.cfg"
        timeout 60 "$VIBIDD" -c "$1.cfg" --log-level notice 2> "$1.log" || fail "$1: vibidd exit $? ($(cat "$1.log"))"
    }
    # body FILE: the rows without the columns that may differ (gap_samples, flags)
    # the recursive estimator's rows: a refinement (flag W) differs by design, a gap (the NaN
    # capture) skips the window, a response value taken out is left out of its fit
    body() { grep -v '^#' "$1" | awk -F, -v OFS=, 'NR > 1 && $NF !~ /W/ { NF -= 2; print }'; }
    config_csv v0.cfg ""
    glitched cap_nan.csv nan
    run nan cap_nan.csv ""
    [ "$(status_val gaps nan.status)" = 1 ] && [ "$(status_val outlier_samples nan.status)" = 0 ] ||
        fail "nan: gaps $(status_val gaps nan.status), outlier_samples $(status_val outlier_samples nan.status)"
    for g in 1.0 1e3 1e300; do
        glitched "cap_$g.csv" "$g"
        run "o$g" "cap_$g.csv" ""
        st="o$g.status"
        [ "$(status_val outlier_samples "$st")" = 1 ] && [ "$(status_val nonfinite_samples "$st")" = 0 ] &&
            [ "$(status_val gaps "$st")" = 0 ] ||
            fail "x1 = $g: outlier_samples $(status_val outlier_samples "$st"), nonfinite_samples $(status_val nonfinite_samples "$st"), gaps $(status_val gaps "$st")"
        cmp -s <(body nan.csv) <(body "o$g.csv") || fail "x1 = $g: tracks differ from the NaN capture's: $(diff <(body nan.csv) <(body "o$g.csv") | head -4)"
        # flags: the same everywhere except G -> O on the row that covers sample 8000 (8199)
        diff <(grep -v '^#' nan.csv | awk -F, '{ print $2, $(NF - 1), $NF }') \
             <(grep -v '^#' "o$g.csv" | awk -F, '{ print $2, $(NF - 1), $NF }') > flags.diff
        [ "$(grep -c '^<' flags.diff)" = 1 ] && grep -q '^< 8199 1 G$' flags.diff && grep -q '^> 8199 0 O$' flags.diff ||
            fail "x1 = $g: flags differ from the NaN capture's beyond G -> O at 8199: $(cat flags.diff)"
        grep -q "outlier: sample 8000: x1 = .* taken out" "o$g.log" || fail "x1 = $g: not logged: $(cat "o$g.log")"
        # the raw recording has the glitch as received (the recorder writes %.17g)
        awk -F, -v g="$g" 'NR == 8003 { exit !($2 == g + 0) }' "o$g.raw.csv" ||
            fail "x1 = $g: the raw recording's sample 8000 is $(sed -n 8003p "o$g.raw.csv")"
        # without the test: P, U or E (no estimate) on every row from the glitch to the end
        # (which of them for 1e300 depends on the build's floating-point path: RelWithDebInfo
        # P/U, the sanitizer build E)
        run "off$g" "cap_$g.csv" "estimator = { outlier_threshold = 0; };"
        bad=$(grep -v '^#' "off$g.csv" | awk -F, 'NR > 1 && $2 > 8000 && $NF !~ /[PUE]/' | wc -l)
        [ "$bad" = 0 ] ||
            fail "x1 = $g without the outlier test: $bad rows after the glitch without P, U or E (the case proves nothing)"
        note "x1 = $g: taken out, tracks equal to the NaN capture's; without the test every later row P, U or E"
    done
    # the recording replays to the same tracks (the glitch is found again)
    run replay o1e300.raw.csv ""
    [ "$(status_val outlier_samples replay.status)" = 1 ] || fail "replay of the recording: outlier_samples $(status_val outlier_samples replay.status)"
    cmp -s <(grep -v '^#' o1e300.csv) <(grep -v '^#' replay.csv) || fail "the recording's replay differs"
    ;;
hostile_names)
    # Issue 30, item 3: a stand or channel name with a line break, a comma or '%n%s' used to
    # pass: InfluxDB answered 400, the status file got a second state= line, the log forged
    # lines, the recording could not be replayed. Names are now of the safe set
    # A-Z a-z 0-9 _ - . (vibid/cfgread.h), checked where they are read: vibidd --check and a
    # run refuse each hostile name with exit 2 and a one-line error naming file, line, field
    # and the character, before any output exists. And names using every character of the
    # set go through every file output intact: the tracks CSV parses (as many fields in
    # every row as in the header, the parameter columns named), every line protocol line
    # has its three space-separated parts and the tags, the status file one state= line,
    # the raw recording replays to the same tracks.
    $GEN "$STAND" --duration 4 --noise 0.001 --seed 5 --csv cap.csv 2>/dev/null || fail "generator"
    for bad in 'rig\nstate=stopped' 'rig,7' '%n%s%s%s%x'; do
        # the name as written in the file (libconfig's \n: a line break in the name)
        sed "s|name = \"paper_example1\";|name = \"$(printf '%s' "$bad" | sed 's/\\/\\\\/g')\";|" "$STAND" > bad_stand.cfg
        grep -qF "name = \"$bad\";" bad_stand.cfg || fail "test setup: name not replaced"
        config_csv v.cfg ""
        sed -i "s|^stand = .*|stand = \"bad_stand.cfg\";|" v.cfg
        sed -i 's|outputs = { tracks = { path = "tracks.csv"; };|outputs = { tracks = { path = "tracks.csv"; }; influx = { path = "t.lp"; };|' v.cfg
        rm -f tracks.csv status t.lp
        for mode in --check run; do
            if [ $mode = run ]; then args=""; else args=--check; fi
            timeout 30 "$VIBIDD" -c v.cfg $args > out 2> err
            rc=$?
            [ $rc = 2 ] || fail "stand name '$bad' ($mode): exit $rc, expected 2 ($(cat err))"
            [ "$(wc -l < err)" = 1 ] || fail "stand name '$bad' ($mode): the error is not one line: $(cat err)"
            grep -q 'bad_stand.cfg:[0-9]*: stand.name: .* (character [0-9]*): a name is' err ||
                fail "stand name '$bad' ($mode): $(cat err)"
        done
        [ ! -e tracks.csv ] && [ ! -e status ] && [ ! -e t.lp ] || fail "stand name '$bad': outputs written"
        note "refused: $(cat err)"
    done
    # every character of the set, in every kind of name the outputs carry
    sed -e 's|name = "paper_example1";|name = "Rig_07-b.2";|' -e 's|"m1"|"m-1.a"|g' -e 's|"c1"|"c_1-k.a"|' \
        -e 's|"x1"|"x_1-a.b"|' "$STAND" > good_stand.cfg
    grep -q '"c_1-k.a"' good_stand.cfg && grep -q '"x_1-a.b"' good_stand.cfg || fail "test setup: good_stand.cfg"
    config_csv v.cfg ""
    sed -i -e "s|^stand = .*|stand = \"good_stand.cfg\";|" -e 's|name = "x1";|name = "x_1-a.b";|' v.cfg
    sed -i 's|outputs = { tracks = { path = "tracks.csv"; };|outputs = { tracks = { path = "tracks.csv"; }; influx = { path = "t.lp"; site = "plant-1.b_2"; }; record = { path = "raw.csv"; };|' v.cfg
    timeout 60 "$VIBIDD" -c v.cfg 2> log || fail "safe names: vibidd exit $? ($(cat log))"
    grep -v '^#' tracks.csv | awk -F, 'NR == 1 { n = NF; next } NF != n { exit 1 }' || fail "tracks: rows with other field counts"
    grep -v '^#' tracks.csv | head -1 | grep -q '^time_s,index,c_1-k.a,c_1-k.a_se,d,' || fail "tracks header: $(grep -v '^#' tracks.csv | head -1)"
    [ "$(data_rows tracks.csv)" = 40 ] || fail "tracks: $(data_rows tracks.csv) rows"
    awk 'NF != 3 || $1 != "vibid,site=plant-1.b_2,stand=Rig_07-b.2" || $2 !~ /^c_1-k\.a=/ { exit 1 }' t.lp ||
        fail "line protocol: $(head -2 t.lp)"
    [ "$(wc -l < t.lp)" = 40 ] || fail "line protocol: $(wc -l < t.lp) lines"
    [ "$(grep -c '^state=' status)" = 1 ] && [ "$(status_val stand)" = Rig_07-b.2 ] || fail "status: $(cat status)"
    sed -n 2p raw.csv | grep -qx 't,x_1-a.b,x2,s' || fail "raw recording header: $(sed -n 2p raw.csv)"
    sed -i "s|file = \"cap.csv\";|file = \"raw.csv\";|" v.cfg
    timeout 60 "$VIBIDD" -c v.cfg --tracks tracks2.csv --influx "" --record "" --status "" 2> log2 ||
        fail "replay of the recording: $(cat log2)"
    cmp -s <(grep -v '^#' tracks.csv) <(grep -v '^#' tracks2.csv) || fail "the recording does not replay to the same tracks"
    note "safe names through tracks, line protocol, status and recording: ok"
    ;;
size_limits)
    # Issue 30, item 8: one 4 MiB line in a stand file took 9.7 s (16 MiB over 100 s) in
    # libconfig's scanner, nothing bounded a file, and 10^5 elements took 61 s in --check
    # (the unit's ExecStartPre). Every file of the one reader (vibid/cfgread.h) is refused
    # beyond 65536 characters a line or 16 MiB with its @includes, naming file and line,
    # exit 2: the stand file, vibidd's configuration, a channel map. (The loader's own test,
    # model.test_stand_file, has the limits exactly, the includes and 10^5 elements.)
    $GEN "$STAND" --duration 1 --noise 0.001 --seed 5 --csv cap.csv 2>/dev/null || fail "generator"
    python3 -c "import sys; s = open(sys.argv[1]).read(); open('long_stand.cfg', 'w').write(s.replace('name = \"paper_example1\";', 'name = \"' + 'a' * (4 << 20) + '\";'))" "$STAND"
    config_csv v.cfg ""
    sed -i 's|^stand = .*|stand = "long_stand.cfg";|' v.cfg
    timeout 30 "$VIBIDD" -c v.cfg --check > out 2> err
    rc=$?
    [ $rc = 2 ] || fail "4 MiB line in the stand file: exit $rc ($(head -c 300 err))"
    grep -q 'long_stand.cfg:[0-9]*: line longer than 65536 characters' err || fail "stand: $(head -c 300 err)"
    config_csv v.cfg ""
    printf '# %070000d\n' 0 >> v.cfg
    timeout 30 "$VIBIDD" -c v.cfg --check > out 2> err
    rc=$?
    [ $rc = 2 ] && grep -q "v.cfg:$(wc -l < v.cfg): line longer than 65536 characters" err ||
        fail "long line in vibidd's configuration: exit $rc ($(head -c 300 err))"
    config_csv v.cfg ""
    sed -n '/channels = (/,/);/p' v.cfg > map.cfg
    printf '# %070000d\n' 0 >> map.cfg
    sed -i -e '/channels = (/,/);/d' -e 's|time_column = "t";|time_column = "t"; channel_map = "map.cfg";|' v.cfg
    timeout 30 "$VIBIDD" -c v.cfg --check > out 2> err
    rc=$?
    [ $rc = 2 ] && grep -q "map.cfg:$(wc -l < map.cfg): line longer than 65536 characters" err ||
        fail "long line in the channel map: exit $rc ($(head -c 300 err))"
    note "refused: $(head -c 200 err)"
    ;;
units)
    # Issue 12, item 9: a capture in mm (x1, x2) and um (s), declared so in the channel map,
    # gives the estimates of the same capture in m: the values are converted to the stand's
    # units. The only difference is the rounding of the scaled copy (17 significant
    # digits, then x 1e-3 / 1e-6), about 1e-16 relative per value: the parameters and
    # their standard errors agree to 1e-9 relative; the modes' standard errors go through
    # a central difference with a 1e-6 relative step (modal.cpp), which amplifies the
    # eigenvalues' rounding by 1e6 or more (up to 1.5e-6 seen), so they get 1e-4, a
    # thousandth of a percent of an error bar. A unit ignored is a factor 1e3 off.
    # Before, the units were ignored: c1, c2 came out 1e6 off. And a unit that does not fit
    # the quantity stops the start with file:line.
    $GEN "$STAND" --duration 10 --noise 0.001 --seed 21 --csv cap.csv 2>/dev/null || fail "generator"
    [ "$(head -1 cap.csv)" = "t,x1,x2,s" ] || fail "test setup: capture header $(head -1 cap.csv)"
    awk -F, 'NR == 1 { print; next } { printf "%s,%.17g,%.17g,%.17g\n", $1, $2 * 1000, $3 * 1000, $4 * 1e6 }' \
        cap.csv > capmm.csv
    config_csv m.cfg ""
    sed -e 's|file = "cap.csv"|file = "capmm.csv"|' -e 's|unit = "m"; column = "x\([12]\)"|unit = "mm"; column = "x\1"|' \
        -e 's|unit = "m"; column = "s"|unit = "um"; column = "s"|' -e 's|tracks.csv|tracks_mm.csv|' m.cfg > mm.cfg
    [ "$(grep -c 'unit = "mm"' mm.cfg)" -eq 2 ] && grep -q 'unit = "um"' mm.cfg || fail "test setup: units not replaced"
    "$VIBIDD" -c mm.cfg --check > check.out 2> log || fail "--check: $(cat log)"
    grep -q "m1.displacement <- source channel 'x1' x 0.001 (its unit to the stand's m)" check.out ||
        fail "--check does not state the conversion of x1: $(grep channel check.out)"
    grep -q "base.displacement <- source channel 's' x 1e-06" check.out || fail "--check: no conversion of s"
    timeout 60 "$VIBIDD" -c m.cfg 2> log || fail "m: vibidd exit $? ($(cat log))"
    timeout 60 "$VIBIDD" -c mm.cfg 2> log || fail "mm: vibidd exit $? ($(cat log))"
    final=$(check_final tracks_mm.csv 1.0) || exit 1
    python3 - tracks.csv tracks_mm.csv <<'PY' || fail "tracks of the capture in mm differ from those in m"
import sys
def rows(p):
    lines = [l.rstrip("\n").split(",") for l in open(p) if not l.startswith("#")]
    # the recursive estimator's rows (the refinement's, flag W, converge to 1e-4 of their
    # standard errors, not to rounding)
    return lines[0], [l for l in lines[1:] if "W" not in l[-1]]
ha, ra = rows(sys.argv[1]); hb, rb = rows(sys.argv[2])
assert ha == hb and len(ra) == len(rb) == 100, (len(ra), len(rb))
worst = 0.0
for a, b in zip(ra, rb):
    for name, x, y in zip(ha, a, b):
        try: x, y = float(x), float(y)
        except ValueError:
            assert x == y, (name, x, y); continue
        d = abs(x - y) / max(abs(x), 1e-300) if x != y else 0.0
        modal_se = name.endswith("_hz_se") or (name.startswith("zeta") and name.endswith("_se"))
        assert d <= (1e-4 if modal_se else 1e-9), (name, x, y, d)
        if not modal_se: worst = max(worst, d)
print(f"[units] 100 rows, parameters and their se within {worst:.2g} relative of the capture in m")
PY
    sed 's|unit = "um"; column = "s"|unit = "kN"; column = "s"|' mm.cfg > bad.cfg
    "$VIBIDD" -c bad.cfg --check > /dev/null 2> log; rc=$?
    [ $rc -eq 2 ] || fail "a force unit on the base displacement: exit $rc, expected 2"
    grep -q "bad.cfg:[0-9]*: source.channels.s.unit: 'kN' is not a length unit for a base_displacement channel" log ||
        fail "message: $(cat log)"
    note "$final; kN on a displacement refused: $(grep -o 'source.channels.s.unit.*' log | cut -c1-80)"
    ;;
clock_step)
    # Issue 12, item 10: a candump log whose clock jumps 1e6 s forward at one frame and 5 s
    # back at a later one. Before, a paced replay waited for the 1e6 s (11.6 days). Now both
    # are clock faults, the times are re-based, every sample is used (the counter numbers
    # them) and the estimates equal those of the unmodified log exactly (only the time
    # column differs); a paced run at x20 over 10 s ends in well under the 60 s bound.
    $GEN "$STAND" --duration 10 --noise 0.001 --seed 22 --candump cap.log 2>/dev/null || fail "generator"
    awk '{ t = substr($1, 2, length($1) - 2) + 0
           if (NR >= 20000) t += 1e6
           if (NR >= 40000) t -= 5
           printf "(%.6f) %s %s\n", t, $2, $3 }' cap.log > step.log
    [ "$(wc -l < step.log)" -eq 60000 ] || fail "test setup: $(wc -l < step.log) lines"
    config_candump v.cfg ""
    sed 's|file = "cap.log"|file = "step.log"|; s|tracks.csv|tracks_step.csv|' v.cfg > step.cfg
    timeout 60 "$VIBIDD" -c v.cfg 2> log0 || fail "unmodified log: $(cat log0)"
    start=$(date +%s.%N)
    timeout 60 "$VIBIDD" -c step.cfg --pace --speed 20 2> log || fail "paced replay of the stepped log: exit $? ($(tail -3 log))"
    took=$(echo "$(date +%s.%N) - $start" | bc)
    [ "$(status_val faults_clock status)" = 2 ] || fail "faults_clock = $(status_val faults_clock status), expected 2"
    [ "$(status_val samples status)" = 20000 ] || fail "samples $(status_val samples status), expected 20000"
    [ "$(status_val missing_samples status)" = 0 ] || fail "missing samples $(status_val missing_samples status)"
    grep -q "step.log:20000: time steps +1e+06 s from the previous frame" log || fail "no clock fault at line 20000: $(grep -i clock log | head -2)"
    grep -Eq "step.log:40000: time steps -(4\.99|5)" log || fail "no clock fault at line 40000"
    cut -d, -f3- tracks.csv | grep -v '^#' > a.txt
    cut -d, -f3- tracks_step.csv | grep -v '^#' > b.txt
    [ "$(head -2 tracks.csv | tail -1 | cut -d, -f1-2)" != "" ] || fail "test setup"
    cmp a.txt b.txt || fail "estimates of the stepped log differ from the unmodified log"
    note "2 clock steps (+1e6 s, -5 s) counted, 20000 samples, estimates identical; paced x20 replay of 10 s took $took s"
    ;;
prometheus)
    # outputs.prometheus (issue 14 item 3): a paced replay serves its metrics on a loopback
    # port; the exposition passes `promtool check metrics`; a scrape and the status file
    # written from the same snapshot agree; hostile peers (one that sends nothing, garbage,
    # 50 connections at once) neither stall nor stop vibidd; SIGTERM with connections open
    # stops it within 1 s; an address in use is a configuration error (exit 2).
    command -v promtool > /dev/null || fail "promtool not found (Debian package prometheus: scripts/install-deps.sh --test)"
    $GEN "$STAND" --duration 60 --noise 0.001 --seed 14 --csv cap.csv 2>/dev/null || fail "generator"
    config_prometheus v.cfg
    # --check binds and releases the address; one not on this host is refused (exit 2)
    timeout 10 "$VIBIDD" -c v.cfg --check > check.out 2> check.err || fail "--check: $(cat check.err)"
    grep -q '^  prometheus = { listen = "127.0.0.1:0"; };' check.out || fail "--check printout: $(grep prometheus check.out)"
    sed 's|listen = "127.0.0.1:0"|listen = "192.0.2.1:18813"|' v.cfg > far.cfg
    timeout 10 "$VIBIDD" -c far.cfg --check > /dev/null 2> far.err; rc=$?
    [ $rc -eq 2 ] || fail "--check with 192.0.2.1 (not on this host): exit $rc, expected 2"
    grep -q 'outputs.prometheus.listen 192.0.2.1:18813: cannot listen: Cannot assign requested address' far.err ||
        fail "--check error: $(cat far.err)"
    timeout 60 "$VIBIDD" -c v.cfg --pace 2> log &
    pid=$!
    trap 'kill $pid 2>/dev/null; rm -rf "$W"' EXIT  # a failure must not leave vibidd running
    target=$(wait_metrics_listen) || fail "no metrics_listen in the status file: $(cat log)"
    port=${target##*:}
    grep -q "metrics: Prometheus exposition at http://127.0.0.1:$port/metrics" log || fail "no start-up notice: $(cat log)"
    URL=http://127.0.0.1:$port/metrics
    sleep 1.5  # a few rows
    curl -s --max-time 5 -D headers -o scrape.txt "$URL" || fail "curl $URL: exit $?"
    grep -qi '^Content-Type: text/plain; version=0.0.4; charset=utf-8' headers || fail "headers: $(cat headers)"
    promtool check metrics < scrape.txt > promtool.out 2>&1 || fail "promtool check metrics: $(cat promtool.out)"
    # the same snapshot in both: a scrape between two reads of an unchanged status file
    # has its samples, uptime, rows, last row and estimates (to the status file's precision)
    same=0
    for _ in $(seq 30); do
        cp status s1; curl -s --max-time 5 -o m.txt "$URL" || fail "curl"; cp status s2
        if cmp -s s1 s2 && [ "$(metric vibid_samples_total m.txt)" = "$(status_val samples s1)" ]; then same=1; break; fi
        sleep 0.05
    done
    [ $same -eq 1 ] || fail "no scrape matched an unchanged status file in 30 tries"
    s=$(status_val samples s1)
    [ "$s" -gt 0 ] || fail "samples $s"
    awk -v a="$(metric vibid_uptime_seconds m.txt)" -v b="$(status_val uptime_s s1)" 'BEGIN { exit !(sprintf("%.3f", a) == b) }' ||
        fail "uptime: metrics $(metric vibid_uptime_seconds m.txt), status $(status_val uptime_s s1)"
    [ "$(metric vibid_last_row_index m.txt)" = "$(status_val last_index s1)" ] || fail "last row index differs"
    [ "$(metric vibid_rows_total m.txt)" = "$(status_val rows s1)" ] || fail "rows differ"
    for p in c1 d c2; do
        mv=$(metric "vibid_estimate{parameter=\"$p\"}" m.txt) sv=$(status_val "estimate.$p" s1)
        awk -v a="$mv" -v b="$sv" 'BEGIN { exit !(sprintf("%.10g", a) == b) }' || fail "estimate $p: metrics $mv, status $sv"
    done
    c1=$(metric 'vibid_estimate{parameter="c1"}' m.txt)
    awk -v c="$c1" 'BEGIN { exit !(c > 0.99 * 2.5e5 && c < 1.01 * 2.5e5) }' || fail "c1 = $c1, truth 2.5e5"
    [ "$(metric vibid_stand_sample_rate_hertz m.txt)" = 2000 ] || fail "stand rate"
    grep -q '^vibid_latency_seconds_count [1-9]' m.txt || fail "no latency measured in a paced run"
    note "scrape = status file at $s samples (uptime, rows, last row, c1 d c2 alike); promtool accepts $(grep -vc '^#' scrape.txt) samples"
    # hostile peers: one that sends nothing, kept open; the others are served meanwhile
    exec 3<> "/dev/tcp/127.0.0.1/$port" || fail "connect"
    t0=$(date +%s%N) t_idle=$(date +%s%N)
    curl -s --max-time 2 -o /dev/null "$URL" || fail "scrape beside an idle connection: curl exit $?"
    dt=$((($(date +%s%N) - t0) / 1000000))
    [ $dt -lt 500 ] || fail "scrape beside an idle connection took $dt ms"
    # garbage: 400 at once
    exec 5<> "/dev/tcp/127.0.0.1/$port" || fail "connect"
    printf 'GARBAGE\r\n\r\n' >&5
    IFS= read -r -t 2 line <&5 || fail "no answer to garbage"
    exec 5<&-
    [ "${line%$'\r'}" = "HTTP/1.1 400 Bad Request" ] || fail "garbage answered '$line'"
    # the idle connection is closed at the 2 s deadline, without an answer
    IFS= read -r -t 4 line <&3; rc=$?
    [ $rc -eq 1 ] || fail "the idle connection was not closed by the deadline (read status $rc, '$line')"
    exec 3<&-
    dt_idle=$((($(date +%s%N) - t_idle) / 1000000))
    [ $dt_idle -ge 1500 ] && [ $dt_idle -le 3000 ] || fail "the idle connection was closed after $dt_idle ms, not at 2 s"
    # 50 connections at once, half of them idle, half with a request
    python3 - "$port" <<'PYEOF' || fail "50 connections: python failed"
import socket, sys, time
port = int(sys.argv[1])
conns = []
for i in range(50):
    s = socket.create_connection(("127.0.0.1", port), timeout=5)
    if i % 2:
        s.sendall(b"GET /metrics HTTP/1.1\r\nHost: x\r\n\r\n")
    conns.append(s)
time.sleep(0.5)
for s in conns:
    s.close()
PYEOF
    curl -s --max-time 2 -o after.txt "$URL" || fail "scrape after 50 connections: curl exit $?"
    grep -q '^vibid_samples_total [1-9]' after.txt || fail "scrape after 50 connections: $(head -c 300 after.txt)"
    sleep 0.5  # the endpoint's counters reach the text at the next render (every 0.2 s here)
    curl -s --max-time 2 -o counts.txt "$URL" || fail "curl"
    awk '$1 == "vibid_metrics_refused_total{reason=\"timeout\"}" && $2 >= 1 { t = 1 }
         $1 == "vibid_metrics_refused_total{reason=\"bad_request\"}" && $2 >= 1 { b = 1 }
         $1 == "vibid_metrics_refused_total{reason=\"evicted\"}" && $2 >= 1 { e = 1 }
         $1 == "vibid_metrics_scrapes_total" && $2 >= 5 { s = 1 } END { exit !(t && b && e && s) }' counts.txt ||
        fail "endpoint counters: $(grep vibid_metrics_ counts.txt | grep -v '^#')"
    # SIGTERM with an idle connection and a half-sent request open: stopped within 1 s
    exec 3<> "/dev/tcp/127.0.0.1/$port" || fail "connect"
    exec 4<> "/dev/tcp/127.0.0.1/$port" || fail "connect"
    printf 'GET /metr' >&4
    kill -0 $pid || fail "vibidd died: $(cat log)"
    kill -TERM $pid
    t0=$(date +%s%N)
    wait $pid; rc=$?
    dt=$((($(date +%s%N) - t0) / 1000000))
    exec 3<&- 4<&-
    [ $rc -eq 0 ] || fail "exit status $rc after SIGTERM: $(cat log)"
    [ $dt -lt 1000 ] || fail "took $dt ms to stop after SIGTERM with connections open"
    [ "$(status_val state status)" = stopped ] || fail "status not final"
    ! grep -Eq '^vibidd: (error|warning):' log || fail "errors in the log: $(grep -E '^vibidd: (error|warning):' log)"
    note "idle connection closed after $dt_idle ms (deadline 2 s), garbage 400, 50 connections survived ($(metric 'vibid_metrics_refused_total{reason="evicted"}' counts.txt) evicted); SIGTERM stopped vibidd in $dt ms"
    # an address in use: --check warns (exit 0, noted in the printout), start-up exits 2
    python3 - > busy.port <<'PYEOF' &
import socket, time
s = socket.socket(); s.bind(("127.0.0.1", 0)); s.listen(1)
print(s.getsockname()[1], flush=True)
time.sleep(8)
PYEOF
    py=$!
    for _ in $(seq 50); do [ -s busy.port ] && break; sleep 0.1; done
    bp=$(cat busy.port)
    sed "s|listen = \"127.0.0.1:0\"|listen = \"127.0.0.1:$bp\"|" v.cfg > busy.cfg
    timeout 10 "$VIBIDD" -c busy.cfg --check > busy.out 2> busy.err || fail "--check on a busy port: exit $? ($(cat busy.err))"
    grep -q "^# outputs.prometheus.listen 127.0.0.1:$bp is in use now" busy.out || fail "--check note: $(tail -3 busy.out)"
    timeout 10 "$VIBIDD" -c busy.cfg --status "" --tracks "" 2> busy.log; rc=$?
    kill $py 2>/dev/null; wait $py 2>/dev/null
    [ $rc -eq 2 ] || fail "start on a busy port: exit $rc, expected 2 ($(cat busy.log))"
    grep -q "outputs.prometheus.listen 127.0.0.1:$bp: cannot listen: Address already in use" busy.log ||
        fail "busy port message: $(cat busy.log)"
    note "a port in use: --check warns, start-up exits 2 naming the address"
    ;;
prometheus_server)
    # A real Prometheus server (Debian's /usr/bin/prometheus) scrapes a running vibidd every
    # second; its query API must return vibid_samples_total > 0, consistent with the status
    # file (not above the samples vibidd counted by then), the estimates and the info labels.
    if ! command -v prometheus > /dev/null; then
        echo "SKIPPED [$CASE]: the prometheus binary is not installed (Debian package prometheus,"
        echo "SKIPPED [$CASE]: scripts/install-deps.sh --test); the real-server test was NOT run"
        exit 77
    fi
    $GEN "$STAND" --duration 60 --noise 0.001 --seed 15 --csv cap.csv 2>/dev/null || fail "generator"
    config_prometheus v.cfg
    timeout 90 "$VIBIDD" -c v.cfg --pace 2> log &
    pid=$!
    target=$(wait_metrics_listen) || fail "no metrics_listen in the status file: $(cat log)"
    pport=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
    printf '%s\n' "global:" "  scrape_interval: 1s" "  scrape_timeout: 1s" "  evaluation_interval: 1s" \
        "scrape_configs:" "  - job_name: vibidd" "    static_configs:" "      - targets: ['$target']" > prometheus.yml
    timeout 90 prometheus --config.file="$W/prometheus.yml" --storage.tsdb.path="$W/tsdb" \
        --web.listen-address="127.0.0.1:$pport" --log.level=warn > prom.log 2>&1 &
    ppid=$!
    trap 'kill $ppid $pid 2>/dev/null; wait; rm -rf "$W"' EXIT
    API="http://127.0.0.1:$pport/api/v1/query"
    v=
    for _ in $(seq 60); do
        v=$(prom_query "$API" vibid_samples_total)
        [ -n "$v" ] && [ "$v" != 0 ] && break
        kill -0 $ppid 2>/dev/null || fail "prometheus exited: $(cat prom.log)"
        sleep 0.5
    done
    [ -n "$v" ] && [ "$v" -gt 0 ] 2>/dev/null ||
        fail "no vibid_samples_total > 0 from the query API in 30 s (got '$v'): $(tail -5 prom.log)"
    s=$(status_val samples status)
    # the stored sample was scraped at most ~1 s ago: not above what vibidd counts now, and
    # not more than 3 s of samples (2 kHz) below it
    [ "$v" -le "$s" ] || fail "Prometheus has $v samples, the status file only $s"
    [ "$v" -ge $((s - 3 * 2000)) ] || fail "Prometheus' $v samples lag the status file's $s by more than 3 s"
    [ "$(prom_query "$API" 'up{job="vibidd"}')" = 1 ] || fail "up{job=\"vibidd\"} is not 1"
    [ "$(prom_query "$API" 'vibid_info{stand="paper_example1",source="replay",estimator="rls"}')" = 1 ] ||
        fail "vibid_info labels"
    c1=$(prom_query "$API" 'vibid_estimate{parameter="c1"}')
    awk -v c="$c1" 'BEGIN { exit !(c > 0.99 * 2.5e5 && c < 1.01 * 2.5e5) }' || fail "c1 via Prometheus = '$c1', truth 2.5e5"
    scrapes=$(status_val metrics_scrapes status)
    [ "$scrapes" -ge 1 ] || fail "the status file counts no scrape"
    kill -TERM $pid
    wait $pid || fail "vibidd exit status $?: $(cat log)"
    kill $ppid; wait $ppid 2>/dev/null
    note "Prometheus ($(prometheus --version 2>&1 | head -1 | cut -d' ' -f3)) stored vibid_samples_total = $v (status file: $s), c1 = $c1, $scrapes scrapes of vibidd"
    ;;
*)
    fail "unknown case"
    ;;
esac
exit 0
