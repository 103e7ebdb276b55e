#!/usr/bin/env bash
# Does vibidd keep up at 10 kHz with the state-space estimator on a 3-DOF stand on one
# core? (issue 16). Prints figures; never passes or fails on time.
# usage: bench/bench_vibidd_ekf.sh BUILD_DIR [SECONDS]
#
# The stand: a chain ground - m1 - m2 - m3 (2, 1.5, 1 kg), springs and dampers between
# them, a measured force on m1 (band-limited noise to 1.5 kHz), only x3 measured, 1 %
# sensor noise; the three springs and three dampers unknown, started 17-20 % off
# (tests/ident/test_ekf.c's chain3, at 10 kHz). vibid-sim writes SECONDS of it as CSV.
#  1. Replay as fast as possible, pinned to one core (taskset -c 0), wall clock including
#     start-up, best of 3: method ekf (the 3-DOF EKF: 12 states, 6 parameters) and the
#     yardstick in the same run, the same capture with every mass measured and the
#     automatic estimator (IV), i.e. what vibidd costs when the stand is fully measured.
#     The EKF keeps up at 10 kHz on one core when its rate is above 10,000 samples/s.
#  2. Paced replay at 10 kHz (--pace: every sample handed over at its time, as CAN frames
#     arrive), both threads pinned to one core: CPU use, latency from hand-over to the
#     updated estimate (p50, p99, over the whole run: the start at the 1000th sample, when
#     the filter runs over the start window at once, is a one-time backlog), ring high-water
#     mark (a replay waits for a full ring instead of dropping; a live source's 65536-slot
#     ring would count overflows). SECONDS >= 8.
set -u
BUILD=$(cd "${1:?usage: bench_vibidd_ekf.sh BUILD_DIR [SECONDS]}" && pwd)
DUR=${2:-20}
SRC=$(cd "$(dirname "$0")/.." && pwd)
VIBIDD=$BUILD/daemon/vibidd
SIM=$BUILD/sim/vibid-sim
W=$(mktemp -d /tmp/vd_bench_ekf_XXXXXX)
trap 'kill $(jobs -p) 2>/dev/null; rm -rf "$W"' EXIT
cd "$W"
RATE=10000
N=$((DUR * RATE))

# stand MEASURE3 MEASURE12: the chain; MEASURE* = a node's measure group or empty
stand() {
    cat <<EOF
stand = { name = "chain3"; sample_rate = $RATE.0;
  nodes = ( { name = "m1"; mass = 2.0; $2 },
            { name = "m2"; mass = 1.5; $3 },
            { name = "m3"; mass = 1.0; $1 } );
  elements = ( { name = "k1"; kind = "spring"; between = ["m1", "ground"]; unknown = true; value = 4.8e4; true_value = 4.0e4; },
               { name = "d1"; kind = "damper"; between = ["m1", "ground"]; unknown = true; value = 16.0; true_value = 20.0; },
               { name = "k2"; kind = "spring"; between = ["m1", "m2"]; unknown = true; value = 2.5e4; true_value = 3.0e4; },
               { name = "d2"; kind = "damper"; between = ["m1", "m2"]; unknown = true; value = 18.0; true_value = 15.0; },
               { name = "k3"; kind = "spring"; between = ["m2", "m3"]; unknown = true; value = 2.4e4; true_value = 2.0e4; },
               { name = "d3"; kind = "damper"; between = ["m2", "m3"]; unknown = true; value = 8.0; true_value = 10.0; } );
  inputs = ( { name = "f"; node = "m1"; gain = 1.0; channel = "F"; } ); };
EOF
}
stand 'measure = { displacement = "x3"; };' 'measure = { displacement = "x1"; };' \
    'measure = { displacement = "x2"; };' > full.cfg
stand 'measure = { displacement = "x3"; };' '' '' > end.cfg
cat > sim.cfg <<EOF
simulation = { seed = 11; excitation = ( { target = "f"; kind = "noise"; amplitude = 20.0; f_high = 1500.0; } );
  noise = ( { channel = "x1"; snr_db = 40.0; }, { channel = "x2"; snr_db = 40.0; }, { channel = "x3"; snr_db = 40.0; } ); };
EOF
"$SIM" -c full.cfg -s sim.cfg --duration "$DUR" --fast --csv cap.csv -q || exit 1

# vdcfg OUT STAND METHOD CHANNELS
vdcfg() {
    cat > "$1" <<EOF
stand = "$2";
source = { kind = "replay"; file = "cap.csv"; time_column = "t";
  channels = ( $4
    { name = "F"; quantity = "force"; node = 0; unit = "N"; column = "F"; } ); };
estimator = { method = "$3"; };
outputs = { tracks = { path = "tracks.csv"; }; status = { path = "status"; interval = 0.5; }; };
EOF
}
X3='{ name = "x3"; quantity = "displacement"; node = 2; unit = "m"; column = "x3"; },'
X12='{ name = "x1"; quantity = "displacement"; node = 0; unit = "m"; column = "x1"; },
    { name = "x2"; quantity = "displacement"; node = 1; unit = "m"; column = "x2"; },'
vdcfg ekf.cfg "$W/end.cfg" ekf "$X3"
vdcfg full_auto.cfg "$W/full.cfg" auto "$X12 $X3"

. "$SRC/bench/bench_common.sh"

echo "vibidd state-space benchmark: 3-DOF chain, only x3 (and the force) measured, $N samples ($DUR s at 10 kHz), $(nproc) CPUs, load $(cut -d' ' -f1-3 /proc/loadavg)"
echo "1. replay throughput, pinned to one core (best of 3, wall clock incl. start-up)"
for c in ekf full_auto; do
    best=0
    for _ in 1 2 3; do
        rm -f tracks.csv status
        t0=$(ns)
        taskset -c 0 "$VIBIDD" -c $c.cfg --log-level error || exit 1
        t1=$(ns)
        r=$(awk -v n=$N -v ns=$((t1 - t0)) 'BEGIN { printf "%.0f", n / (ns * 1e-9) }')
        [ "$r" -gt "$best" ] && best=$r
    done
    last=$(grep -v '^#' tracks.csv | tail -1)
    printf "   %-44s %'9d samples/s = %5.1fx real time at 10 kHz\n" \
        "$([ $c = ekf ] && echo "ekf, x3 only (6 unknowns, 12 states):" || echo "yardstick: auto (IV), x1 x2 x3 measured:")" \
        "$best" "$(awk -v r="$best" 'BEGIN { print r / 10000 }')"
    echo "      last row: $(echo "$last" | cut -d, -f1-16)"
done
echo "   (truth k1 4e4, d1 20, k2 3e4, d2 15, k3 2e4, d3 10)"

# CPU over the middle of the run: from 3 s to at most 13 s (the capture must outlast it)
secs=$(awk -v d="$DUR" 'BEGIN { t = d - 5; print (t > 10 ? 10 : t) }')
echo "2. paced replay at 10 kHz, both threads pinned to one core (CPU over $secs s)"
rm -f tracks.csv status
taskset -c 0 "$VIBIDD" -c ekf.cfg --pace --log-level error &
pid=$!
sleep 3
read -r du ds dns < <(cpu_window $pid "$secs")
kill -TERM $pid
wait $pid
awk -v du="$du" -v ds="$ds" -v hz="$(getconf CLK_TCK)" -v ns="$dns" \
    -v p50="$(status_get latency_us_p50 status)" -v p99="$(status_get latency_us_p99 status)" \
    -v n="$(status_get samples status)" -v hw="$(status_get ring_high_water status)" \
    -v ov="$(status_get ring_overflows status)" -v cap="$(status_get ring_capacity status)" \
    'BEGIN { w = ns * 1e-9; printf "   ekf: CPU %5.1f %% of one core (user %.1f, sys %.1f); latency p50 %s us, p99 %s us; %s samples, ring high water %s of %s, overflows %s\n",
             100 * (du + ds) / hz / w, 100 * du / hz / w, 100 * ds / hz / w, p50, p99, n, hw, cap, ov }'
