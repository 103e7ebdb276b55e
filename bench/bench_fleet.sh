#!/usr/bin/env bash
# Benchmark of vibidd's network outputs for a fleet (issue 14): prints figures, never passes
# or fails on time. usage: bench/bench_fleet.sh BUILD_DIR [SECONDS] [REPEATS]
# (needs vibidd and tests/daemon/vd_gen_capture in BUILD_DIR; Debian's mosquitto and
# mosquitto-clients). The stand is the paper's example 1 at 1 kHz (RLS, 200 Hz pre-filter).
#  a. Messages per second one vibidd publishes to a local mosquitto: an unpaced replay
#     (`--replay CAPTURE`, as fast as it goes) of a 30 s capture with decimation 1 (a track
#     row per sample, 30 000 messages, QoS 1) and a queue that holds them all (nothing
#     dropped); a subscriber (mosquitto_sub -q 1, receive times with -F %U) counts what it
#     got. Printed: messages received over the time from vibidd's start to the last message,
#     the steady rate between the first and the last message, vibidd's own time to its exit
#     (estimation and drain), and the CPU of vibidd, broker and subscriber.
#  b. The CPU one stand costs at 1 kHz, paced (`--pace`: a sample handed over every ms, as
#     a live source does; decimation 100 = 10 track rows/s, status every second), for each
#     variant of outputs: "none" (tracks CSV and status file only: the yardstick, measured in
#     the same run) and "mqtt" (the same plus outputs.mqtt to the local broker). CPU time from
#     /proc/PID/task/*/schedstat (ns, all threads) over a window of SECONDS (default 20) in
#     the steady state (after 2 s), the variants alternated REPEATS times (default 3), the
#     median printed; the broker's CPU over the same window is its share for that stand.
#  c. From b: how many such stands one host carries, under the stated assumption: the
#     daemons plus the broker's share per stand use at most 70 % of all cores (the rest for
#     the system, Telegraf or Prometheus, and bursts), with every stand like this one. At
#     10 rows/s MQTT's own cost is close to b.'s run-to-run spread, so c. also gives the
#     figure from a model: b.'s yardstick plus 11 messages/s at a.'s CPU per message (vibidd
#     with minus without MQTT, and the broker).
#     With Debian's influxd (package influxdb) also: a2. lines per second one vibidd writes to
#     InfluxDB over HTTP (the same unpaced replay, outputs.influx.http with a buffer that holds
#     them all, batches of 5000; the points counted back through the query API), and in b.
#     the variants "influx" (outputs.influx.http to the local influxd, no authentication) and
#     "both" (MQTT and InfluxDB at once), the server's CPU in the window as its share.
# A further variant is one more call of run_variant with its own block of outputs.
set -euo pipefail
BUILD=$(cd "${1:?usage: bench_fleet.sh BUILD_DIR [SECONDS] [REPEATS]}" && pwd)
SECS=${2:-20}
REPS=${3:-3}
SRC=$(cd "$(dirname "$0")/.." && pwd)
VIBIDD=$BUILD/daemon/vibidd
GEN=$BUILD/tests/daemon/vd_gen_capture
MOSQUITTO=$(command -v mosquitto || echo /usr/sbin/mosquitto)
for x in "$VIBIDD" "$GEN" "$MOSQUITTO"; do [ -x "$x" ] || { echo "bench_fleet: $x missing" >&2; exit 1; }; done
command -v mosquitto_sub > /dev/null || { echo "bench_fleet: mosquitto_sub missing (Debian: mosquitto-clients)" >&2; exit 1; }
W=$(mktemp -d /tmp/vd_bench_fleet_XXXXXX)
PIDS=()
cleanup() {
    exec 2> /dev/null # (bash's job notices of the processes killed here)
    for p in "${PIDS[@]}"; do kill -9 "$p" || true; done # (some have ended already)
    wait || true
    rm -rf "$W"
}
trap cleanup EXIT
cd "$W"
. "$SRC/bench/bench_common.sh"

# cpu_ns PID: CPU time of all threads of PID so far, ns (schedstat: no 10 ms ticks)
cpu_ns() { cat /proc/"$1"/task/*/schedstat 2> /dev/null | awk '{ s += $1 } END { printf "%.0f\n", s }'; }
free_port() { python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }
median() { sort -g | awk '{ v[NR] = $1 } END { print (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2 }'; }

sed 's/^\( *sample_rate = \)2000\.0;/\11000.0;/' "$SRC/examples/stands/paper_example1.cfg" > stand1k.cfg
grep -q 'sample_rate = 1000.0;' stand1k.cfg || { echo "bench_fleet: cannot make the 1 kHz stand" >&2; exit 1; }
"$GEN" stand1k.cfg --duration 30 --noise 0.001 --seed 7 --csv cap_a.csv 2> /dev/null
"$GEN" stand1k.cfg --duration $((SECS + 6)) --noise 0.001 --seed 8 --csv cap_b.csv 2> /dev/null

# The broker: loopback, anonymous, no per-message log lines (their cost is not the broker's);
# no limit on the messages queued for a subscriber that falls behind (mosquitto's default of
# 1000 drops the rest: in a. the subscriber is slower than vibidd)
PORT=$(free_port)
printf '%s\n' "listener $PORT 127.0.0.1" "allow_anonymous true" "log_dest file $W/broker.log" \
    "log_type error" "log_type warning" "log_type notice" "max_queued_messages 0" > broker.conf
[ "$(id -u)" = 0 ] && echo "user root" >> broker.conf
"$MOSQUITTO" -c broker.conf > broker.out 2>&1 &
BPID=$!
PIDS+=("$BPID")
for _ in $(seq 50); do
    python3 -c "import socket; socket.create_connection(('127.0.0.1', $PORT), timeout=0.2)" 2> /dev/null && break
    sleep 0.1
done
python3 -c "import socket; socket.create_connection(('127.0.0.1', $PORT), timeout=0.2)" 2> /dev/null ||
    { echo "bench_fleet: mosquitto did not start: $(cat broker.out)" >&2; exit 1; }

# InfluxDB (optional: the variants need Debian's influxd): loopback, no authentication (its
# cost is a per-request check, not per line), data under $W, started once for a2. and b.
INFLUXD=$(command -v influxd || true)
IPID=0 IPORT=0
if [ -n "$INFLUXD" ]; then
    IPORT=$(free_port)
    . "$SRC/tests/support/influxd_conf.sh"
    influxd_conf influx.conf "$W/influx" "$IPORT" false
    "$INFLUXD" -config influx.conf > influxd.out 2>&1 &
    IPID=$!
    PIDS+=("$IPID")
    for _ in $(seq 100); do curl -s -o /dev/null "http://127.0.0.1:$IPORT/ping" && break; sleep 0.1; done
    curl -s -XPOST "http://127.0.0.1:$IPORT/query" --data-urlencode "q=CREATE DATABASE vibid" > /dev/null ||
        { echo "bench_fleet: influxd did not start: $(tail -3 influxd.out)" >&2; exit 1; }
fi

# config FILE CAPTURE DECIMATION EXTRA_OUTPUTS: the stand's pipeline with tracks, status and
# EXTRA_OUTPUTS (more groups inside outputs = { ... })
config() {
    cat > "$1" << EOF
stand = "$W/stand1k.cfg";
source = {
  kind = "replay"; file = "$2"; time_column = "t";
  channels = (
    { name = "x1"; quantity = "displacement"; node = 0; unit = "m"; column = "x1"; },
    { name = "x2"; quantity = "displacement"; node = 1; unit = "m"; column = "x2"; },
    { name = "s";  quantity = "base_displacement"; node = 0; unit = "m"; column = "s"; }
  );
};
estimator = { method = "rls"; prefilter_hz = 200.0; decimation = $3; };
outputs = {
  tracks = { path = "tracks.csv"; };
  status = { path = "status"; interval = 1.0; };
  $4
};
EOF
}

echo "vibidd fleet benchmark: paper example 1 at 1 kHz, $(nproc) CPUs, $(uname -r), load $(cut -d' ' -f1-3 /proc/loadavg); mosquitto $("$MOSQUITTO" -h 2> /dev/null | sed -n 's/^mosquitto version //p' | head -1)"

# ---- a. messages per second ---------------------------------------------------------------
stdbuf -oL mosquitto_sub -h 127.0.0.1 -p "$PORT" -q 1 -F '%U %t' -t 'vibid/v1/bench/a/tracks' -t vibid/probe > sub_a.out 2> sub_a.err &
SPID=$!
PIDS+=("$SPID")
for _ in $(seq 50); do
    mosquitto_pub -h 127.0.0.1 -p "$PORT" -q 1 -t vibid/probe -m ready 2> /dev/null || true
    grep -q ' vibid/probe$' sub_a.out && break
    sleep 0.1
done
grep -q ' vibid/probe$' sub_a.out || { echo "bench_fleet: subscriber not ready: $(cat sub_a.err)" >&2; exit 1; }
config a.cfg cap_a.csv 1 "mqtt = { url = \"mqtt://127.0.0.1:$PORT\"; site = \"bench\"; stand = \"a\"; queue_size = 40000; drain_timeout = 60.0; };"
rm -f tracks.csv status
b0=$(cpu_ns $BPID) s0=$(cpu_ns $SPID)
t0=$(ns)
(
    "$VIBIDD" -c a.cfg --replay cap_a.csv --tracks "" --log-level warning 2> a.log &
    wait $! || echo "bench_fleet: vibidd exit status $? in a: $(tail -3 a.log)" >&2
    read -r -a st < "/proc/$BASHPID/stat"
    echo "${st[15]} ${st[16]}" > a.cpu
)
t1=$(ns)
rows=$(status_get rows status)
got=0 still=0
while [ "$still" -lt 20 ]; do # the subscriber may still be receiving: until all, or 2 s without one
    n=$(grep -c ' vibid/v1/bench/a/tracks$' sub_a.out || true)
    [ "$n" -ge "$rows" ] && break
    if [ "$n" -gt "$got" ]; then got=$n still=0; else still=$((still + 1)); fi
    sleep 0.1
done
b1=$(cpu_ns $BPID) s1=$(cpu_ns $SPID)
kill "$SPID"
read -r vu vs < a.cpu
grep ' vibid/v1/bench/a/tracks$' sub_a.out | awk -v t0="$t0" -v t1="$t1" -v rows="$rows" -v hz="$(getconf CLK_TCK)" \
    -v vu="$vu" -v vs="$vs" -v bns=$((b1 - b0)) -v sns=$((s1 - s0)) -v pub="$(status_get mqtt_published status)" \
    -v drop="$(status_get mqtt_dropped status)" '
    NR == 1 { first = $1 } { last = $1; n++ }
    END {
      start = t0 / 1e9; el = last - start
      printf "a. one vibidd, unpaced replay, decimation 1: %d track rows, %d acknowledged by the broker (%d dropped), %d received\n", rows, pub, drop, n
      printf "   %.0f messages/s received over %.2f s from vibidd'\''s start to the last message; steady %.0f messages/s between the first and the last\n", n / el, el, (n - 1) / (last - first)
      printf "   vibidd exited after %.2f s (estimation, publishing, drain); CPU: vibidd %.2f s (user %.2f, sys %.2f), broker %.2f s, subscriber %.2f s\n", (t1 - t0) / 1e9, (vu + vs) / hz, vu / hz, vs / hz, bns / 1e9, sns / 1e9
      printf "%.0f\n", n / el > "a.rate"
      printf "%d %.0f %.0f %.0f\n", rows, (vu + vs) / hz * 1e9, bns, sns > "a.cost"
    }'

# the yardstick of a.: the same replay without outputs.mqtt (what estimation and rows alone take)
config a0.cfg cap_a.csv 1 ""
t0=$(ns)
(
    "$VIBIDD" -c a0.cfg --replay cap_a.csv --tracks "" --log-level warning 2> a0.log &
    wait $! || echo "bench_fleet: vibidd exit status $? in a (no MQTT): $(tail -3 a0.log)" >&2
    read -r -a st < "/proc/$BASHPID/stat"
    echo "${st[15]} ${st[16]}" > a0.cpu
)
t1=$(ns)
read -r vu vs < a0.cpu
read -r arows avib abro asub < a.cost
awk -v el=$((t1 - t0)) -v hz="$(getconf CLK_TCK)" -v vu="$vu" -v vs="$vs" -v rows="$(status_get rows status)" -v ra="$(cat a.rate)" \
    -v arows="$arows" -v avib="$avib" -v abro="$abro" -v asub="$asub" 'BEGIN {
    r = rows / (el / 1e9)
    printf "   the same replay without MQTT: %d rows in %.2f s (%.0f rows/s), CPU %.2f s: %s\n", rows, el / 1e9, r, (vu + vs) / hz,
           (r > 1.2 * ra) ? "publishing, not the estimation, limits the rate above" : "the estimation itself limits the rate above"
    v = (avib - (vu + vs) / hz * 1e9) / arows; b = abro / arows; s = asub / arows
    printf "   CPU per message: vibidd %.1f us (with MQTT minus without), broker %.1f us, subscriber %.1f us\n", v / 1e3, b / 1e3, s / 1e3
    printf "%.0f %.0f\n", v, b > "a.permsg" }'
echo "   (broker, subscriber and vibidd share this host's $(nproc) cores: the rate is the host's, with all three on it)"

# ---- a2. lines per second to InfluxDB ------------------------------------------------------
if [ "$IPID" != 0 ]; then
    config a2.cfg cap_a.csv 1 "influx = { stand = \"a2\"; http = { url = \"http://127.0.0.1:$IPORT\"; buffer_size = 64; drain_timeout = 120.0; }; };"
    rm -f tracks.csv status
    b0=$(cpu_ns $IPID)
    t0=$(ns)
    (
        "$VIBIDD" -c a2.cfg --replay cap_a.csv --tracks "" --log-level warning 2> a2.log &
        wait $! || echo "bench_fleet: vibidd exit status $? in a2: $(tail -3 a2.log)" >&2
        read -r -a st < "/proc/$BASHPID/stat"
        echo "${st[15]} ${st[16]}" > a2.cpu
    )
    t1=$(ns)
    b1=$(cpu_ns $IPID)
    read -r vu vs < a2.cpu
    pts=$(curl -s -XPOST "http://127.0.0.1:$IPORT/query" --data-urlencode "db=vibid" \
        --data-urlencode "q=SELECT count(\"index\") FROM vibid WHERE stand = 'a2'" |
        python3 -c 'import json, sys; r = json.load(sys.stdin)["results"][0]; print(r["series"][0]["values"][0][1] if "series" in r else 0)')
    read -r a0u a0s < a0.cpu
    awk -v el=$((t1 - t0)) -v hz="$(getconf CLK_TCK)" -v vu="$vu" -v vs="$vs" -v rows="$(status_get rows status)" \
        -v w="$(status_get influx_http_written status)" -v req="$(status_get influx_http_requests status)" \
        -v pts="$pts" -v bns=$((b1 - b0)) -v a0="$((a0u + a0s))" 'BEGIN {
        printf "a2. one vibidd, the same unpaced replay to InfluxDB over HTTP: %d rows, %d lines written in %d requests, %d points in the database\n", rows, w, req, pts
        printf "   %.0f lines/s from vibidd'\''s start to its exit (every line written); CPU: vibidd %.2f s, influxd %.2f s\n", w / (el / 1e9), (vu + vs) / hz, bns / 1e9
        printf "   CPU per line: vibidd %.2f us (with InfluxDB minus without), influxd %.2f us\n", ((vu + vs) - a0) / hz * 1e6 / rows, bns / 1e3 / rows }'
fi

# ---- b. CPU per stand at 1 kHz, paced -----------------------------------------------------
# run_variant NAME EXTRA_OUTPUTS [SERVER_PID...]: one paced run of the stand with these extra
# outputs; appends "vibidd_ns server_ns window_ns n_servers" to NAME.res (server_ns: the sum
# over the servers given, e.g. the broker)
run_variant() {
    local name=$1 extra=$2 pid w0 w1 v0 v1 k0=0 k1=0 p
    shift 2
    config "b_$name.cfg" cap_b.csv 100 "$extra"
    rm -f tracks.csv status
    "$VIBIDD" -c "b_$name.cfg" --replay cap_b.csv --pace --log-level warning 2> "b_$name.log" &
    pid=$!
    PIDS+=("$pid")
    sleep 2
    for p in "$@"; do k0=$((k0 + $(cpu_ns "$p"))); done
    v0=$(cpu_ns $pid)
    w0=$(ns)
    sleep "$SECS"
    v1=$(cpu_ns $pid)
    w1=$(ns)
    for p in "$@"; do k1=$((k1 + $(cpu_ns "$p"))); done
    kill -TERM $pid
    wait $pid || echo "bench_fleet: vibidd ($name) exit status $?: $(tail -3 "b_$name.log")" >&2
    grep -E '^vibidd: (error|warning):' "b_$name.log" >&2 || true
    echo "$((v1 - v0)) $((k1 - k0)) $((w1 - w0)) $#" >> "$name.res"
}
VARIANTS="none mqtt"
[ "$IPID" != 0 ] && VARIANTS="none mqtt influx both"
echo "b. one stand at 1 kHz, paced, decimation 100 (10 rows/s): CPU over $SECS s windows, $REPS runs per variant alternated"
for r in $(seq "$REPS"); do
    run_variant none ""
    run_variant mqtt "mqtt = { url = \"mqtt://127.0.0.1:$PORT\"; site = \"bench\"; stand = \"b\"; };" "$BPID"
    if [ "$IPID" != 0 ]; then
        run_variant influx "influx = { stand = \"b\"; http = { url = \"http://127.0.0.1:$IPORT\"; }; };" "$IPID"
        run_variant both "mqtt = { url = \"mqtt://127.0.0.1:$PORT\"; site = \"bench\"; stand = \"b\"; };
  influx = { stand = \"b\"; http = { url = \"http://127.0.0.1:$IPORT\"; }; };" "$BPID" "$IPID"
    fi
done
for v in $VARIANTS; do
    vib=$(awk '{ print 100 * $1 / $3 }' "$v.res" | median)
    srv=$(awk '{ print 100 * $2 / $3 }' "$v.res" | median)
    all=$(awk '{ printf "%.2f ", 100 * $1 / $3 }' "$v.res")
    if [ "$(awk '{ print $4; exit }' "$v.res")" = 0 ]; then srvt="no server"; else srvt=$(printf 'server share %.3f %%' "$srv"); fi
    printf '   %-5s vibidd %5.2f %% of one core (runs: %s), %s\n' "$v" "$vib" "$all" "$srvt"
    echo "$v $vib $srv" >> b.summary
done

# ---- c. stands per host -------------------------------------------------------------------
ncpu=$(nproc)
awk -v ncpu="$ncpu" '
    $1 == "none" { base = $2 }
    { name[NR] = $1; vib[NR] = $2; srv[NR] = $3 }
    END {
      printf "c. stands at 1 kHz one %d-core host carries, keeping the daemons plus the servers'\'' share under 70 %% of all cores:\n", ncpu
      for (i = 1; i <= NR; i++) {
        per = vib[i] + srv[i]
        printf "   %-5s %5.2f %% of one core per stand (%+.2f %% against no network output) -> %d stands\n", name[i], per, per - base, int(70 * ncpu / per)
      }
      printf "   (assumed: every stand like this one: 3 channels, 3 unknowns, 10 rows/s; the subscriber (Telegraf) elsewhere or within the 30 %% left)\n"
      # the same from the costs per message of a. (the difference in b. is close to its spread)
      getline pm < "a.permsg"; split(pm, c, " ")
      per = base + 11 * (c[1] + c[2]) / 1e9 * 100
      printf "   model (mqtt): no output %.2f %% + 11 messages/s (10 rows, 1 status) x (vibidd %.1f + broker %.1f us) = %.2f %% per stand -> %d stands\n", base, c[1] / 1e3, c[2] / 1e3, per, int(70 * ncpu / per)
    }' b.summary
