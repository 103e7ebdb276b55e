#!/usr/bin/env bash
# The loopback demo's plot (examples/demo/plot_loopback.gp) shows the convergence: on tracks
# whose errors settle from 5 % to 0.02 % with standard errors from 1 % to 0.01 % (a
# synthetic file, so that the expected ranges are known), each panel's y range holds the
# truth (0) and the last row's +-2 se band, and spans less than 0.5 % (a fixed +-5 % axis,
# as before, drew these errors as flat lines). The PNG is written.
# Usage: demo_plot.sh SRC_DIR
set -euo pipefail
src=$1
command -v gnuplot > /dev/null || { echo "FAIL: gnuplot not found (Debian package gnuplot-nox: scripts/install-deps.sh)"; exit 1; }
W=$(mktemp -d /tmp/vd_demo_plot.XXXXXX)
trap 'rm -rf "$W"' EXIT
cd "$W"
awk 'BEGIN { print "# vibidd tracks (synthetic)"; print "time_s,index,c1,c1_se,d,d_se,c2,c2_se,flags";
  for (i = 1; i <= 100; i++) { f = exp(-i / 8); e = 0.05 * f + 0.0002; s = 0.01 * f + 0.0001;
    printf "%.3f,%d,%.10g,%.10g,%.10g,%.10g,%.10g,%.10g,\n", 1000 + i * 0.2, i * 400, 2.5e5 * (1 + e), 2.5e5 * s,
           300 * (1 - 2 * e), 300 * 2 * s, 1.5e6 * (1 + e / 2), 1.5e6 * s / 2 } }' > tracks.csv
gnuplot -e "tracks='tracks.csv'; png='tracks.png'; c1t=2.5e5; dt=300; c2t=1.5e6" \
        "$src/examples/demo/plot_loopback.gp" 2> ranges.txt || { echo "FAIL: gnuplot: $(cat ranges.txt)"; exit 1; }
[ "$(stat -c %s tracks.png)" -gt 10000 ] || { echo "FAIL: tracks.png not written"; exit 1; }
# the last row's error +- 2 se in %: c1 0.02 +- 0.02, d -0.04 +- 0.04, c2 0.01 +- 0.01
for spec in "c1 0.0 0.04" "d -0.08 0.0" "c2 0.0 0.02"; do
    set -- $spec
    r=$(sed -n "s/^yrange $1: //p" ranges.txt)
    [ -n "$r" ] || { echo "FAIL: no range printed for $1: $(cat ranges.txt)"; exit 1; }
    awk -v r="$r" -v lo="$2" -v hi="$3" 'BEGIN { split(r, a, ":");
        exit !(a[1] <= lo - 1e-9 && a[2] >= hi + 1e-9 && a[1] <= 0 && a[2] >= 0 && a[2] - a[1] < 0.5) }' ||
        { echo "FAIL: $1: y range $r does not hold [$2, $3] and 0 within a span < 0.5 %"; exit 1; }
    echo "$1: y range $r % (last row's band [$2, $3] %)"
done
echo "PASS: demo_plot"
