#!/usr/bin/env bash
# The main job: vibid-sim as a virtual shaker controller serving the paper's example 1
# over Modbus TCP on 127.0.0.1, and vibidd acquiring from it at 2 kHz (FIFO mode) and
# identifying c1, d, c2 in real time. Prints the converging estimates against the truth
# from the stand file, and leaves the tracks (CSV), the raw recording, the status file
# and a PNG plot in OUT_DIR.
# Usage: loopback_demo.sh BUILD_DIR OUT_DIR [SECONDS]
set -euo pipefail
build=$(cd "$1" && pwd) out=$2 seconds=${3:-20}
src=$(cd "$(dirname "$0")/../.." && pwd)
stand="$src/examples/stands/paper_example1.cfg"
mkdir -p "$out"
out=$(cd "$out" && pwd)
rm -f "$out"/tracks.csv "$out"/raw.csv "$out"/vibidd.status "$out"/tracks.png

"$build/sim/vibid-sim" -c "$stand" -s "$src/examples/demo/loopback_sim.cfg" \
    --modbus 127.0.0.1:0 --duration $((seconds + 10)) > "$out/sim.out" 2> "$out/sim.log" &
sim_pid=$!
daemon_pid=
cleanup() { kill "$sim_pid" ${daemon_pid:+"$daemon_pid"} 2>/dev/null || true; }
trap cleanup EXIT
port=
for _ in $(seq 100); do
  port=$(sed -n 's/.*listening on 127.0.0.1:\([0-9]*\).*/\1/p' "$out/sim.out")
  [[ -n "$port" ]] && break
  sleep 0.1
done
[[ -n "$port" ]] || { echo "demo: vibid-sim did not start: $(cat "$out/sim.log")" >&2; exit 1; }

# The shipped example configuration, pointed at this run's port and output folder.
sed -e "s|^stand = .*|stand = \"$stand\";|" \
    -e "s|tcp://127.0.0.1:[0-9]*|tcp://127.0.0.1:$port|" \
    "$src/daemon/examples/modbus_fifo.cfg" > "$out/vibidd.cfg"
( cd "$out" && exec "$build/daemon/vibidd" -c vibidd.cfg 2> vibidd.log ) &
daemon_pid=$!

truth() { sed -n "s/.*name = \"$1\";.*true_value = \([^;]*\);.*/\1/p" "$stand"; }
c1_true=$(truth c1) d_true=$(truth d) c2_true=$(truth c2)
echo "vibid-sim serves paper example 1 on 127.0.0.1:$port; vibidd identifies (Modbus FIFO, 2 kHz)"
# each estimate with its standard error and the error in standard errors (z): the truth
# should lie within about 2 of them
printf '%8s %10s  %-36s %-36s %-36s\n' "t [s]" samples "c1 [N/m] +- se (error, z)" "d [N s/m] +- se (error, z)" "c2 [N/m] +- se (error, z)"
printf '%8s %10s  %-36s %-36s %-36s\n' truth "" "$c1_true" "$d_true" "$c2_true"
for ((t = 2; t <= seconds; t += 2)); do
  sleep 2
  kill -0 "$daemon_pid" 2>/dev/null || { echo "demo: vibidd stopped: $(cat "$out/vibidd.log")" >&2; exit 1; }
  [[ -f "$out/vibidd.status" ]] || continue
  awk -F= -v t="$t" -v c1t="$c1_true" -v dt="$d_true" -v c2t="$c2_true" '
    { v[$1] = $2 }
    END {
      if (v["estimate.c1"] == "" || v["estimate.c1"] == "nan") { printf "%8d %10s  (no estimate yet)\n", t, v["samples"]; exit }
      printf "%8d %10s  %-36s %-36s %-36s\n", t, v["samples"],
        sprintf("%.6g +- %.2g (%+.3f %%, %+.1f)", v["estimate.c1"], v["estimate.c1_se"], 100 * (v["estimate.c1"] / c1t - 1), (v["estimate.c1"] - c1t) / v["estimate.c1_se"]),
        sprintf("%.5g +- %.2g (%+.3f %%, %+.1f)", v["estimate.d"], v["estimate.d_se"], 100 * (v["estimate.d"] / dt - 1), (v["estimate.d"] - dt) / v["estimate.d_se"]),
        sprintf("%.6g +- %.2g (%+.3f %%, %+.1f)", v["estimate.c2"], v["estimate.c2_se"], 100 * (v["estimate.c2"] / c2t - 1), (v["estimate.c2"] - c2t) / v["estimate.c2_se"]) }' "$out/vibidd.status"
done
kill -TERM "$daemon_pid"
wait "$daemon_pid" || { echo "demo: vibidd exit status $?: $(cat "$out/vibidd.log")" >&2; exit 1; }
daemon_pid=
echo "status: $(grep -E '^(samples|gaps|faults|source_failed_polls|latency_us_p50|latency_us_p99)=' "$out/vibidd.status" | tr '\n' ' ')"

if command -v gnuplot >/dev/null; then
  gnuplot -e "tracks='$out/tracks.csv'; png='$out/tracks.png'; c1t=$c1_true; dt=$d_true; c2t=$c2_true" \
          "$src/examples/demo/plot_loopback.gp"
  echo "plot: $out/tracks.png"
fi
echo "tracks: $out/tracks.csv (columns: docs/vibidd.md), raw recording: $out/raw.csv"
