#!/usr/bin/env bash
# Benchmark of vibidd (figures printed, never pass/fail on time).
# usage: bench/bench_vibidd_replay.sh BUILD_DIR [SECONDS]
#  1. replay throughput of the paper's example 1 (2 kHz, 3 channels, 3 unknowns, RLS with
#     the pre-filter, one track row per 200 samples) from a candump log and from a CSV
#     capture, as fast as possible: samples/s (best of 3 runs, wall clock incl. start-up);
#  2. CPU use (user+sys over wall time) of a paced replay delivering 1 kHz and 10 kHz
#     (the 2 kHz capture at --speed 0.5 and 5), and the daemon's own latency figures,
#     frame receipt (source read returns) -> estimate updated, median and p99.
set -u
BUILD=${1:?usage: bench_vibidd_replay.sh BUILD_DIR [SECONDS]}
DUR=${2:-60}
SRC=$(cd "$(dirname "$0")/.." && pwd)
VIBIDD=$BUILD/daemon/vibidd
GEN=$BUILD/tests/daemon/vd_gen_capture
STAND=$SRC/examples/stands/paper_example1.cfg
W=$(mktemp -d /tmp/vd_bench_XXXXXX)
trap 'rm -rf "$W"' EXIT
cd "$W"
"$GEN" "$STAND" --duration "$DUR" --noise 0.001 --csv cap.csv --candump cap.log 2>/dev/null
N=$((DUR * 2000))
cat > cd.cfg <<CFG
stand = "$STAND";
source = { kind = "replay"; file = "cap.log"; dbc = "$SRC/tests/daemon/data/example1.dbc"; counter = "Counter";
  channels = (
    { name = "x1"; quantity = "displacement"; node = 0; signal = "X1"; message = "Sample_A"; },
    { name = "x2"; quantity = "displacement"; node = 1; signal = "X2"; message = "Sample_B"; },
    { name = "s";  quantity = "base_displacement"; node = 0; signal = "S"; message = "Sample_C"; } ); };
estimator = { method = "rls"; prefilter_hz = 200.0; decimation = 200; };
outputs = { tracks = { path = "tracks.csv"; }; status = { path = "status"; interval = 0.5; }; };
CFG
sed 's/file = "cap.log"; dbc = [^;]*; counter = "Counter";/file = "cap.csv"; time_column = "t";/;
     s/signal = "X1"; message = "Sample_A"/column = "x1"/; s/signal = "X2"; message = "Sample_B"/column = "x2"/;
     s/signal = "S"; message = "Sample_C"/column = "s"/' cd.cfg > csv.cfg
echo "vibidd benchmark: paper example 1, $N samples ($DUR s at 2 kHz), $(nproc) CPUs, $(uname -r)"
for kind in cd csv; do
    best=0
    for _ in 1 2 3; do
        rm -f tracks.csv
        t0=$(date +%s%N)
        "$VIBIDD" -c $kind.cfg --log-level error || exit 1
        t1=$(date +%s%N)
        r=$(awk -v n=$N -v ns=$((t1 - t0)) 'BEGIN { printf "%.0f", n / (ns * 1e-9) }')
        [ "$r" -gt "$best" ] && best=$r
    done
    printf "replay throughput (%s): %'d samples/s = %.0fx real time at 2 kHz\n" \
        "$([ $kind = cd ] && echo candump log || echo CSV capture)" "$best" "$(awk -v r=$best 'BEGIN{print r/2000}')"
done
for rate in 1000 10000; do
    speed=$(awk -v r=$rate 'BEGIN { print r / 2000 }')
    secs=$(awk -v d=$DUR -v s=$speed 'BEGIN { t = d / s - 2; print (t > 10 ? 10 : t) }')
    rm -f tracks.csv
    "$VIBIDD" -c cd.cfg --pace --speed "$speed" --log-level error &
    pid=$!
    sleep 1
    read -r u0 s0 < <(awk '{ print $14, $15 }' /proc/$pid/stat)
    t0=$(date +%s%N)
    sleep "$secs"
    read -r u1 s1 < <(awk '{ print $14, $15 }' /proc/$pid/stat)
    t1=$(date +%s%N)
    kill -TERM $pid; wait $pid
    hz=$(getconf CLK_TCK)
    awk -v du=$((u1 - u0)) -v ds=$((s1 - s0)) -v hz="$hz" -v ns=$((t1 - t0)) -v rate=$rate \
        'BEGIN { printf "paced %5d samples/s: CPU %.1f %% of one core (user %.1f %%, sys %.1f %%)\n", rate,
                 100 * (du + ds) / hz / (ns * 1e-9), 100 * du / hz / (ns * 1e-9), 100 * ds / hz / (ns * 1e-9) }'
    echo "  latency receipt -> estimate: p50 $(sed -n 's/^latency_us_p50=//p' status) us, p99 $(sed -n 's/^latency_us_p99=//p' status) us (1 us buckets)"
done
