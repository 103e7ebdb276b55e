#!/usr/bin/env bash
# Benchmark of vibidd on the paper's example 1 (3 channels, 3 unknowns, RLS with the
# 200 Hz pre-filter, one track row per 200 samples). Prints figures; never passes or
# fails on time. usage: bench/bench_vibidd.sh BUILD_DIR [SECONDS]
#  1. Replay throughput from a candump log and from a CSV capture (REPLAY_SECONDS, default
#     300, of 2 kHz data: 600,000 samples, 1.8 M frames), as fast as possible, wall clock
#     including start-up, best of 3: with the daemon's two threads free to use both cores,
#     and pinned to one core (taskset), the issue's measure. The start-up alone (a capture
#     of one sample) is printed beside it: on a short capture it is a large part of the
#     wall clock. Baseline in the same run: bench_replay_source (fgets line count = I/O
#     floor, candump parse, DBC decoding + sample assembly without the estimator) on the
#     SECONDS capture.
#  2. Paced replay delivering 1 kHz and 10 kHz sample by sample (the 2 kHz capture at
#     --speed 0.5 and 5; each sample is handed to the acquisition thread at its time, as
#     CAN frames arrive): CPU use and the daemon's latency from the source handing the
#     sample over to the estimate updated with it, median and p99 (1 us histogram).
#  3. Live acquisition from vibid-sim over Modbus TCP on loopback (FIFO mode, 1 ms polls) at
#     1 kHz and 10 kHz: CPU use of vibidd and of the simulator, latency from the poll
#     response received to the estimate updated (p50/p99), samples, gaps; at 10 kHz also with
#     vibid-sim pinned to CPU 1 and vibidd to CPU 0 (issue 15's measure: p99 under 100 us).
#     Each 10 kHz setting runs with the output-error refinement off, then on (refine_every
#     = 2 s over 5 s windows), back to back, and the latencies are printed beside each other.
#  2 and 3 run with acquisition.handoff_spin = 0 (the estimation thread sleeps when the ring
#  is empty) and 1000 us (it busy-waits first), to show what the thread wake-up costs.
#  BENCH_PARTS selects parts (default 123; BENCH_PARTS=3: the live runs alone, ~3 min).
set -u
BUILD=$(cd "${1:?usage: bench_vibidd.sh BUILD_DIR [SECONDS]}" && pwd) # needs vibidd, vibid-sim, bench/ (build/release has them)
DUR=${2:-60}
RDUR=${REPLAY_SECONDS:-300}
SRC=$(cd "$(dirname "$0")/.." && pwd)
VIBIDD=$BUILD/daemon/vibidd
SIM=$BUILD/sim/vibid-sim
STAND=$SRC/examples/stands/paper_example1.cfg
DBC=$SRC/sim/paper_example1.dbc
W=$(mktemp -d /tmp/vd_bench_XXXXXX)
trap 'kill $(jobs -p) 2>/dev/null; rm -rf "$W"' EXIT
cd "$W"
# The capture: vibid-sim's frames of example 1 with the demo's excitation (5 Hz triangle,
# 60 dB sensor noise), as candump log and CSV.
"$SIM" -c "$STAND" -s "$SRC/examples/demo/loopback_sim.cfg" --duration "$DUR" --fast --epoch 1700000000 \
    --candump cap.log --csv cap.csv -q || exit 1
# BENCH_PARTS: which parts run (default 123; e.g. BENCH_PARTS=3 for the live runs alone)
PARTS=${BENCH_PARTS:-123}
want() { case $PARTS in *"$1"*) return 0 ;; esac; return 1; }
if want 1; then # the long capture is part 1's alone
    "$SIM" -c "$STAND" -s "$SRC/examples/demo/loopback_sim.cfg" --duration "$RDUR" --fast --epoch 1700000000 \
        --candump long.log --csv long.csv -q || exit 1
    head -3 long.log > one.log # one sample: its three frames
    head -2 long.csv > one.csv # the header and one sample
fi
N=$((RDUR * 2000))
cat > chanmap.cfg <<CFG
counter = "SampleCounter";
channels = (
  { name = "x1"; quantity = "displacement"; node = 0; signal = "x1"; },
  { name = "x2"; quantity = "displacement"; node = 1; signal = "x2"; },
  { name = "s";  quantity = "base_displacement"; node = 0; signal = "s"; } );
CFG
cat > cd.cfg <<CFG
stand = "$STAND";
source = { kind = "replay"; file = "cap.log"; dbc = "$DBC"; counter = "SampleCounter";
  channels = (
    { name = "x1"; quantity = "displacement"; node = 0; signal = "x1"; },
    { name = "x2"; quantity = "displacement"; node = 1; signal = "x2"; },
    { name = "s";  quantity = "base_displacement"; node = 0; signal = "s"; } ); };
estimator = { method = "rls"; prefilter_hz = 200.0; decimation = 200; };
outputs = { tracks = { path = "tracks.csv"; }; status = { path = "status"; interval = 0.5; }; };
CFG
sed 's/file = "cap.log"; dbc = [^;]*; counter = "SampleCounter";/file = "cap.csv"; time_column = "t";/;
     s/signal = "x1"/column = "x1"/; s/signal = "x2"/column = "x2"/;
     s/signal = "s"/column = "s"/' cd.cfg > csv.cfg

. "$SRC/bench/bench_common.sh"

for kind in cd csv; do
    ext=$([ $kind = cd ] && echo log || echo csv)
    sed "s/cap\.$ext/long.$ext/" $kind.cfg > long_$kind.cfg
    sed "s/cap\.$ext/one.$ext/" $kind.cfg > one_$kind.cfg
done

echo "vibidd benchmark: paper example 1, $N samples ($RDUR s at 2 kHz) for 1., $((DUR * 2000)) ($DUR s) for 2. and the baseline, $(nproc) CPUs, $(uname -r), load $(cut -d' ' -f1-3 /proc/loadavg)"
if want 1; then
echo "1. replay throughput (best of 3, wall clock incl. start-up)"
# run_ns CFG PIN -> wall-clock ns of one vibidd run
run_ns() {
    local t0 t1
    rm -f tracks.csv
    t0=$(ns)
    if [ "$2" = one ]; then
        taskset -c 0 "$VIBIDD" -c "$1" --log-level error || exit 1
    else
        "$VIBIDD" -c "$1" --log-level error || exit 1
    fi
    t1=$(ns)
    echo $((t1 - t0))
}
for kind in cd csv; do
    for pin in both one; do
        best=0 start=0
        for _ in 1 2 3; do
            s=$(run_ns one_$kind.cfg $pin)
            { [ "$start" = 0 ] || [ "$s" -lt "$start" ]; } && start=$s
            r=$(awk -v n=$N -v ns="$(run_ns long_$kind.cfg $pin)" 'BEGIN { printf "%.0f", n / (ns * 1e-9) }')
            [ "$r" -gt "$best" ] && best=$r
        done
        printf "   %-13s %-19s %'10d samples/s = %5.0fx real time at 2 kHz; start-up and exit alone %.1f ms\n" \
            "$([ $kind = cd ] && echo "candump log" || echo "CSV capture")" \
            "$([ $pin = one ] && echo "(pinned, 1 core):" || echo "(2 cores):")" "$best" \
            "$(awk -v r="$best" 'BEGIN { print r / 2000 }')" "$(awk -v s="$start" 'BEGIN { print s / 1e6 }')"
    done
done
samples=$(status_get samples status)
echo "   (last run: $samples samples estimated, $(status_get rows status) track rows; c1 $(status_get estimate.c1 status)," \
     "d $(status_get estimate.d status), c2 $(status_get estimate.c2 status); truth 2.5e5, 300, 1.5e6)"
echo "   baseline, same capture, one thread, no estimator:"
"$BUILD/bench/bench_replay_source" cap.log "$DBC" chanmap.cfg 2000 3 | sed -n '2,$p' | sed 's/^/ /'

fi

if want 2; then
echo "2. paced replay, sample by sample (CPU over 10 s; latency from the daemon's histogram);"
echo "   handoff_spin = estimation thread busy-waits this long (us) before sleeping"
sed 's/^estimator = /acquisition = { handoff_spin = 1000; };\nestimator = /' cd.cfg > cd_spin.cfg
for rate in 1000 10000; do
  for spin in 0 1000; do
    speed=$(awk -v r=$rate 'BEGIN { print r / 2000 }')
    secs=$(awk -v d="$DUR" -v s="$speed" 'BEGIN { t = d / s - 2; print (t > 10 ? 10 : t) }')
    rm -f tracks.csv status
    "$VIBIDD" -c "$([ $spin = 0 ] && echo cd.cfg || echo cd_spin.cfg)" --pace --speed "$speed" --log-level error &
    pid=$!
    sleep 1
    read -r du ds dns < <(cpu_window $pid "$secs")
    kill -TERM $pid
    wait $pid
    awk -v du="$du" -v ds="$ds" -v hz="$(getconf CLK_TCK)" -v ns="$dns" -v rate=$rate -v spin=$spin \
        -v p50="$(status_get latency_us_p50 status)" -v p99="$(status_get latency_us_p99 status)" \
        'BEGIN { w = ns * 1e-9; printf "   %5d samples/s, handoff_spin %4d: CPU %5.1f %% of one core (user %.1f, sys %.1f); latency p50 %s us, p99 %s us\n",
                 rate, spin, 100 * (du + ds) / hz / w, 100 * du / hz / w, 100 * ds / hz / w, p50, p99 }'
  done
done
fi

if want 3; then
echo "3. live: vibid-sim -> Modbus TCP (loopback, FIFO mode, 1 ms polls) -> vibidd (CPU over 10 s)"
echo "   shared: both programs wherever the scheduler puts them; pinned: vibid-sim on CPU 1, vibidd"
echo "   (all its threads) on CPU 0, as a test stand runs the controller on its own hardware"
echo "   refine: estimator.refine_every in s (0 = off; 2: an output-error fit over the last 5 s"
echo "   every 2 s in the SCHED_IDLE refine thread, docs/vibidd.md \"Refinement\"); at 10 kHz each"
echo "   setting runs with refine 0, then 2, back to back (the same machine load as near as can be)"
# live RATE SPIN PIN REFINE: one 10 s measurement; prints its line, sets P50 and P99
live() {
    local rate=$1 spin=$2 pin=$3 refine=$4 pin_sim=() pin_vd=() sim pid port u0 s0 u1 s1 su0 ss0 su1 ss1 t0 t1
    if [ "$pin" = pinned ]; then
        pin_sim=(taskset -c 1) pin_vd=(taskset -c 0)
    fi
    sed "s/sample_rate = 2000.0;/sample_rate = $rate.0;/" "$STAND" > stand_$rate.cfg
    rm -f sim.out status tracks.csv
    "${pin_sim[@]}" "$SIM" -c stand_$rate.cfg -s "$SRC/examples/demo/loopback_sim.cfg" --modbus 127.0.0.1:0 --duration 40 -q \
        > sim.out 2> sim.log &
    sim=$!
    port=
    for _ in $(seq 100); do
        port=$(sed -n 's/.*listening on 127.0.0.1:\([0-9]*\).*/\1/p' sim.out 2> /dev/null)
        [ -n "$port" ] && break
        sleep 0.1
    done
    [ -n "$port" ] || { echo "vibid-sim did not start: $(cat sim.log)"; exit 1; }
    sed -e "s|^stand = .*|stand = \"$W/stand_$rate.cfg\";|" -e "s|tcp://127.0.0.1:[0-9]*|tcp://127.0.0.1:$port|" \
        -e 's|record = { path = "raw.csv"; };||' -e 's|poll_period = 0.02;|poll_period = 0.001;|' \
        -e "s|realtime_priority = 0;|realtime_priority = 0; handoff_spin = $spin;|" \
        -e "s|^estimator = { decimation = 200; };|estimator = { decimation = 200; refine_every = $refine; refine_window = 5; };|" \
        "$SRC/daemon/examples/modbus_fifo.cfg" > live.cfg
    sed -i 's|path = "vibidd.status"|path = "status"; interval = 0.5|' live.cfg
    "${pin_vd[@]}" "$VIBIDD" -c live.cfg --log-level error &
    pid=$!
    sleep 3
    read -r u0 s0 < <(cpu_of $pid)
    read -r su0 ss0 < <(cpu_of $sim)
    t0=$(ns)
    sleep 10
    read -r u1 s1 < <(cpu_of $pid)
    read -r su1 ss1 < <(cpu_of $sim)
    t1=$(ns)
    kill -TERM $pid
    wait $pid
    kill -TERM $sim 2>/dev/null
    wait $sim 2>/dev/null
    P50=$(status_get latency_us_p50 status) P99=$(status_get latency_us_p99 status)
    awk -v du=$((u1 - u0)) -v ds=$((s1 - s0)) -v sd=$((su1 - su0 + ss1 - ss0)) -v hz="$(getconf CLK_TCK)" \
        -v ns=$((t1 - t0)) -v rate=$rate -v spin=$spin -v p50="$P50" -v p99="$P99" -v n="$(status_get samples status)" \
        -v gaps="$(status_get gaps status)" -v fp="$(status_get source_failed_polls status)" -v pin="$pin" \
        -v refine="$refine" -v rd="$(status_get refinements status)" -v rf="$(status_get refine_failed status)" \
        -v rs="$(status_get refine_skipped status)" -v rt="$(status_get refine_last_duration_s status)" \
        'BEGIN { w = ns * 1e-9; printf "   %-6s %5d samples/s, handoff_spin %4d, refine %s: vibidd CPU %5.1f %% (user %.1f, sys %.1f), vibid-sim %4.1f %%; latency p50 %s us, p99 %s us; %s samples, %s gaps, %s failed polls",
                 pin, rate, spin, refine, 100 * (du + ds) / hz / w, 100 * du / hz / w, 100 * ds / hz / w, 100 * sd / hz / w, p50, p99, n, gaps, fp
                 if (refine > 0) printf "; refinements %s, failed %s, skipped %s, last fit %s s", rd, rf, rs, rt
                 printf "\n" }'
}
side=()
for case in 1000:0:shared 1000:1000:shared 10000:0:shared 10000:1000:shared 10000:0:pinned 10000:1000:pinned; do
    IFS=: read -r rate spin pin <<< "$case"
    if [ "$pin" = pinned ] && [ "$(nproc)" -lt 2 ]; then echo "   (pinned runs need 2 CPUs; skipped)"; continue; fi
    live "$rate" "$spin" "$pin" 0
    [ "$rate" = 10000 ] || continue
    off50=$P50 off99=$P99
    live "$rate" "$spin" "$pin" 2
    side+=("$(printf "   %-6s handoff_spin %4d: p50 %6s -> %6s us, p99 %7s -> %7s us" "$pin" "$spin" "$off50" "$P50" "$off99" "$P99")")
done
if [ ${#side[@]} -gt 0 ]; then
    echo "   10 kHz receipt -> estimate latency, refine off -> on (the runs above; figures, not a verdict):"
    printf '%s\n' "${side[@]}"
fi
fi
