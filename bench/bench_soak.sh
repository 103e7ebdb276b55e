#!/usr/bin/env bash
# Soak benchmark of vibidd (issue 12): HOURS (default 24) of stand time replayed paced at
# xSPEED (default 100: 24 h in 14.4 min) with every output on, the daemon's memory and
# descriptors sampled; both must stay flat. Prints figures; never passes or fails on them.
# usage: bench/bench_soak.sh BUILD_DIR [HOURS] [SPEED] [OUT_DIR]
#  - The stand: the paper's example 1 at 1 kHz (examples/stands/paper_example1.cfg with
#    sample_rate 1000), the demo's excitation and 60 dB sensor noise
#    (examples/demo/loopback_sim.cfg), c2 cracked by 10 % at HOURS/2 and restored HOURS/24
#    later, so that an alarm is raised and cleared in the run.
#  - The capture is never stored: vibid-sim writes the candump log (sim/paper_example1.dbc,
#    3 frames per sample, ~12 GB for 24 h) into a named pipe that vibidd replays with
#    source.paced = true. vibidd opens the capture more than once (a probe for a cut last
#    line, which does not read a pipe, then the reader), so the script holds a reading end
#    of the pipe open that never reads: the pipe survives the probe's close. The replay's
#    sample-rate check would read the pipe ahead of the run, so it runs before, on the first
#    10 s of the same simulation as a file (`vibidd --check`), and the run has
#    --rate-check off.
#  - Every output on: tracks CSV, InfluxDB line protocol to a file and by UDP to a loopback
#    listener that drains it (python3), raw recording (CSV), status file (0.5 s), alarms
#    (all unknowns, learned baselines), log (info, a status line a minute) to a file.
#    Once per simulated hour (by the status file's sample counter) the files are rotated
#    as logrotate would: mv + SIGHUP (vibidd reopens them), the previous hour's files are
#    counted and deleted, so disk use stays at ~2 h of raw recording (~0.7 GB) and a
#    descriptor leaked on reopen would show.
#  - Every 10 s of wall time (1 s in runs shorter than 5 min): VmRSS, VmHWM, threads and
#    open descriptors of vibidd (/proc), its and the simulator's CPU ticks and the status
#    file's samples counter -> OUT_DIR/samples.csv (default out/soak).
#  - Summary: RSS first/last/min/max after the warm-up (the first 60 s of wall time; less in
#    runs shorter than 10 min), its least-squares slope in KiB per simulated hour with its
#    standard error, over the run and over its last third (past the crack's alarm), the
#    verdicts "flat" (slope within 3 standard errors of 0) and "constant" (descriptors),
#    samples vs expected, gaps/faults/write errors, rows of every output summed over the
#    rotated files against the status counters, UDP datagrams sent/received, alarms, CPU,
#    wall time. VmRSS moves in 4 KiB pages: over 24 h one page is 0.17 KiB/h.
#  Exit status 1 only if vibidd or the simulator fails, or samples, rows or reopens are
#  missing (never on the figures).
set -u
BUILD=$(cd "${1:?usage: bench_soak.sh BUILD_DIR [HOURS] [SPEED] [OUT_DIR]}" && pwd) # needs vibidd, vibid-sim
HOURS=${2:-24}
SPEED=${3:-100}
OUT=${4:-out/soak}
SRC=$(cd "$(dirname "$0")/.." && pwd)
VIBIDD=$BUILD/daemon/vibidd
SIM=$BUILD/sim/vibid-sim
DBC=$SRC/sim/paper_example1.dbc
RATE=1000
mkdir -p "$OUT" && OUT=$(cd "$OUT" && pwd) || exit 1
W=$(mktemp -d /tmp/vd_soak_XXXXXX)
trap 'kill $(jobs -p) 2>/dev/null; exec 3<&- 2>/dev/null; rm -rf "$W"' EXIT
cd "$W"
. "$SRC/bench/bench_common.sh"

DUR=$(awk -v h="$HOURS" 'BEGIN { printf "%.6f", h * 3600 }')
N=$(awk -v d="$DUR" -v r=$RATE 'BEGIN { printf "%.0f", d * r }')
PER_HOUR=$((RATE * 3600))
SPEED_F=$(awk -v s="$SPEED" 'BEGIN { printf "%.6f", s }')
# s of wall time before RSS counts, and between samples; shorter for a short check run
read -r WARMUP PERIOD < <(awk -v d="$DUR" -v v="$SPEED" 'BEGIN { w = d / v
    printf "%d %d\n", (w >= 600 ? 60 : (w >= 20 ? w / 10 : 2)), (w >= 300 ? 10 : 1) }')
sed "s/sample_rate = 2000.0;/sample_rate = $RATE.0;/" "$SRC/examples/stands/paper_example1.cfg" > stand.cfg
sed "s/^};\$/  changes = ( { parameter = \"c2\"; at = $(awk -v d="$DUR" 'BEGIN { print d / 2 }'); factor = 0.9; },\\
              { parameter = \"c2\"; at = $(awk -v d="$DUR" 'BEGIN { print d / 2 + d / 24 }'); factor = 1.0; } );\\
};/" "$SRC/examples/demo/loopback_sim.cfg" > sim.cfg
grep -q '^  changes' sim.cfg || { echo "bench_soak: could not add the crack to sim.cfg"; exit 1; }

# the UDP listener: drains the datagrams, counts them and their lines when terminated
python3 - > udp.out <<'EOF' &
import signal, socket, sys
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
s.bind(("127.0.0.1", 0))
print(s.getsockname()[1], flush=True)
n = lines = 0
def stop(*_):
    print(n, lines, flush=True)
    sys.exit(0)
signal.signal(signal.SIGTERM, stop)
while True:
    d = s.recv(65536)
    n += 1
    lines += d.count(b"\n")
EOF
udp=$!
port=
for _ in $(seq 50); do
    port=$(head -1 udp.out)
    [ -n "$port" ] && break
    sleep 0.1
done
[ -n "$port" ] || { echo "bench_soak: the UDP listener did not start"; exit 1; }

cat > soak.cfg <<CFG
stand = "stand.cfg";
source = { kind = "replay"; file = "cap.log"; format = "candump"; paced = true; speed = $SPEED_F;
  dbc = "$DBC"; counter = "SampleCounter";
  channels = (
    { name = "x1"; quantity = "displacement"; node = 0; signal = "x1"; },
    { name = "x2"; quantity = "displacement"; node = 1; signal = "x2"; },
    { name = "s";  quantity = "base_displacement"; node = 0; signal = "s"; } ); };
estimator = { forgetting = 0.9999; };   # auto (IV), memory ~10 s: tracks the crack
outputs = {
  tracks = { path = "tracks.csv"; };
  influx = { path = "tracks.influx"; udp = "127.0.0.1:$port"; };
  record = { path = "raw.csv"; };
  status = { path = "status"; interval = 0.5; }; };
alarms = { };
log = { level = "info"; status_interval = 60.0; };
CFG
cp soak.cfg stand.cfg sim.cfg "$OUT/"

# the sample-rate check (and the configuration) on the first 10 s of the same simulation
"$SIM" -c stand.cfg -s sim.cfg --duration 10 --epoch 1700000000 --candump pre.log -q || exit 1
check=$("$VIBIDD" -c soak.cfg --check --replay pre.log 2>&1) || { echo "bench_soak: vibidd --check: $check"; exit 1; }
rm -f pre.log
rm -f status tracks.csv tracks.influx raw.csv # probe leftovers, if any

echo "vibidd soak benchmark: $HOURS h of stand time ($N samples at $RATE Hz, paper example 1, candump" \
     "through a pipe from vibid-sim) paced x$SPEED; $(nproc) CPUs, $(uname -r), load $(cut -d' ' -f1-3 /proc/loadavg)"
echo "   rate check of the capture's first 10 s: $(echo "$check" | tail -1 | sed 's/^# //')"
mkfifo cap.log
"$SIM" -c stand.cfg -s sim.cfg --duration "$DUR" --epoch 1700000000 --candump cap.log -q 2> sim.log &
sim=$!
exec 3< cap.log # the pipe's reading end that keeps it open across vibidd's probe
t0=$(ns)
"$VIBIDD" -c soak.cfg --rate-check off 2> vibidd.log 3<&- &
pid=$!

rotate() { # tally the previous hour's files, move the current ones away, make vibidd reopen
    local f
    for f in tracks.csv tracks.influx raw.csv; do
        [ -f "$f.1" ] && count "$f.1" && rm -f "$f.1"
        [ -f "$f" ] && mv "$f" "$f.1"
    done
    kill -HUP $pid
    rotations=$((rotations + 1))
}
tr_rows=0 in_rows=0 in_alarms=0 raw_rows=0
count() {
    case $1 in
    tracks.csv*)    tr_rows=$((tr_rows + $(grep -c -v -e '^#' -e '^time_s,' "$1"))) ;;
    tracks.influx*) in_rows=$((in_rows + $(grep -c '^vibid,' "$1")))
                    in_alarms=$((in_alarms + $(grep -c '^vibid_alarm,' "$1"))) ;;
    raw.csv*)       raw_rows=$((raw_rows + $(grep -c -v -e '^#' -e '^t,' "$1"))) ;;
    esac
}

echo "wall_s,sim_h,samples,rss_kib,hwm_kib,fds,threads,cpu_ticks,sim_cpu_ticks" > "$OUT/samples.csv"
rotations=0 next_rot=$PER_HOUR next_sample=$PERIOD
while kill -0 $pid 2>/dev/null; do
    sleep 1
    samples=$( [ -f status ] && status_get samples status); samples=${samples:-0}
    if [ "$samples" -ge "$next_rot" ] && [ "$next_rot" -lt "$N" ]; then
        rotate
        next_rot=$((next_rot + PER_HOUR))
    fi
    el=$((($(ns) - t0) / 1000000000))
    if [ $el -ge $next_sample ]; then
        next_sample=$((next_sample + PERIOD))
        st=$(awk '/^VmRSS:/ { r = $2 } /^VmHWM:/ { h = $2 } /^Threads:/ { t = $2 } END { print r "," h "," t }' \
             /proc/$pid/status 2>/dev/null)
        fds=$(ls /proc/$pid/fd 2>/dev/null | wc -l)
        u= s= su= ss=
        read -r u s < <(cpu_of $pid 2>/dev/null)
        read -r su ss < <(cpu_of $sim 2>/dev/null)
        [ -n "${u:-}" ] && [ "$fds" -gt 0 ] || continue # exited meanwhile
        IFS=, read -r rss hwm thr <<< "$st"
        echo "$el,$(awk -v n="$samples" -v r=$PER_HOUR 'BEGIN { printf "%.4f", n / r }'),$samples,$rss,$hwm,$fds,$thr,$((u + s)),$((${su:-0} + ${ss:-0}))" \
            >> "$OUT/samples.csv"
    fi
done
wait $pid; rc=$?
t1=$(ns)
exec 3<&-
wait $sim; src=$?
for f in tracks.csv tracks.influx raw.csv; do
    for g in "$f.1" "$f"; do [ -f "$g" ] && count "$g"; done
done
kill -TERM $udp; wait $udp
read -r udp_n udp_lines < <(sed -n 2p udp.out)
cp status vibidd.log "$OUT/" 2>/dev/null

fail=0
[ $rc -eq 0 ] || { echo "   vibidd FAILED: exit status $rc; log: $(tail -3 vibidd.log)"; fail=1; }
[ $src -eq 0 ] || { echo "   vibid-sim FAILED: exit status $src: $(tail -3 sim.log)"; fail=1; }
S() { status_get "$1" status; }
samples=$(S samples)
rows=$(S rows)
reopened=$(grep -c 'outputs reopened (SIGHUP)' vibidd.log)
awk -F, -v warm=$WARMUP -v period=$PERIOD -v hours="$HOURS" -v wall=$(((t1 - t0) / 1000000)) -v speed="$SPEED" \
    -v hz="$(getconf CLK_TCK)" '
    NR == 1 { next }
    { n_all++; fmin = (n_all == 1 || $6 < fmin) ? $6 : fmin; fmax = (n_all == 1 || $6 > fmax) ? $6 : fmax
      if (n_all == 1) rss0 = $4
      thr = $7; hwm = $5; cpu = $8; scpu = $9; last_wall = $1 }
    $1 >= warm { n++; x[n] = $2; y[n] = $4; sx += $2; sy += $4
                 if (n == 1) first = $4; last = $4; mx = (n == 1 || $4 > mx) ? $4 : mx; mn = (n == 1 || $4 < mn) ? $4 : mn }
    END {
      printf "   wall time %.1f s for %s h of stand time = x%.1f (aim x%s)\n", wall / 1000, hours, hours * 3600 / (wall / 1000), speed
      if (n < 3) { print "   too few samples after the warm-up for the RSS fit"; exit }
      mxx = sx / n; my = sy / n
      for (i = 1; i <= n; i++) { sxx += (x[i] - mxx) ^ 2; sxy += (x[i] - mxx) * (y[i] - my) }
      b = sxy / sxx
      for (i = 1; i <= n; i++) { r = y[i] - my - b * (x[i] - mxx); ss += r * r }
      se = sqrt(ss / (n - 2) / sxx); span = x[n] - x[1]
      printf "   RSS (VmRSS, %d samples every %d s; after the first %d s): first %d KiB, last %d KiB, min %d, max %d KiB (first sample: %d KiB); VmHWM at the end %d KiB\n",
             n, period, warm, first, last, mn, mx, rss0, hwm
      printf "   RSS slope (least squares over %.2f simulated h): %+.2f +- %.2f KiB per simulated hour = %+.1f KiB over the run (residual sd %.1f KiB)\n",
             span, b, se, b * span, sqrt(ss / (n - 2))
      printf "   open descriptors: min %d, max %d over all %d samples; threads %d\n", fmin, fmax, n_all, thr
      printf "   CPU (until the last sample, %d s): vibidd %.1f %% of one core, vibid-sim writing the capture %.1f %%\n",
             last_wall, 100 * cpu / hz / last_wall, 100 * scpu / hz / last_wall
      # the last third of the run alone: past the crack and its alarm (new code paths touch
      # new pages once), a leak still grows there, a one-off step does not
      m = 0; tx = ty = txx = txy = tss = 0
      for (i = 1; i <= n; i++) if (x[i] >= x[1] + 2 * span / 3) { m++; tx += x[i]; ty += y[i]; i3 = m == 1 ? i : i3 }
      if (m >= 3) {
        tx /= m; ty /= m
        for (i = i3; i <= n; i++) { txx += (x[i] - tx) ^ 2; txy += (x[i] - tx) * (y[i] - ty) }
        b3 = txy / txx
        for (i = i3; i <= n; i++) { r = y[i] - ty - b3 * (x[i] - tx); tss += r * r }
        se3 = sqrt(tss / (m - 2) / txx); span3 = x[n] - x[i3]
        printf "   RSS slope over the last third (%.2f simulated h, %d samples): %+.2f +- %.2f KiB per simulated hour; RSS there %d..%d KiB\n",
               span3, m, b3, se3, y[i3], y[n]
      }
      flat = abs(b) <= 3 * se || (m >= 3 && (abs(b3) <= 3 * se3 || abs(b3 * span3) <= 4))
      printf "   verdict: RSS %s (slope within 3 standard errors of 0, over the run or over its last third, or under one 4 KiB page there), descriptors %s\n",
             flat ? "flat" : "NOT flat", fmin == fmax ? "constant" : "NOT constant"
    }
    function abs(v) { return v < 0 ? -v : v }' "$OUT/samples.csv"
echo "   samples: $samples estimated of $N expected ($(S source_samples) from the source, last index $(S last_index)); gaps $(S gaps)," \
     "missing $(S missing_samples), faults $(S faults), dropped frames $(S source_dropped_frames), bad lines $(S source_bad_lines)," \
     "ring overflows $(S ring_overflows), write errors $(S write_errors), torn lines $(S torn_lines)"
echo "   outputs over $((rotations + 1)) files each ($rotations rotations, $reopened reopens logged): tracks $tr_rows rows," \
     "InfluxDB file $in_rows rows + $in_alarms alarm lines, raw recording $raw_rows rows; status rows $rows"
echo "   InfluxDB UDP: $(S influx_udp_sent) sent, $(S influx_udp_errors) errors; received $udp_n datagrams, $udp_lines lines"
echo "   alarms raised $(S alarms_raised), active at the end: $(S alarms_active | sed 's/^$/none/'); implausible rows $(S implausible_rows); estimates at the end:" \
     "c1 $(S estimate.c1), d $(S estimate.d), c2 $(S estimate.c2) (truth 2.5e5, 300, 1.5e6);" \
     "latency p50 $(S latency_us_p50) us, p99 $(S latency_us_p99) us"
echo "   samples: $OUT/samples.csv; status, log, configurations: $OUT/"
[ "$samples" = "$N" ] && [ "$raw_rows" = "$N" ] || { echo "   SAMPLES MISSING: $samples estimated, $raw_rows recorded, $N expected"; fail=1; }
[ "$tr_rows" = "$rows" ] && [ "$in_rows" = "$rows" ] || { echo "   ROWS MISSING: status $rows, tracks $tr_rows, InfluxDB file $in_rows"; fail=1; }
[ "$reopened" = "$rotations" ] || { echo "   REOPENS MISSING: $rotations SIGHUPs, $reopened reopens logged"; fail=1; }
exit $fail
