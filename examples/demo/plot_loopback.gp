# Tracks of the loopback demo: relative error of each estimate against the truth, with its
# +-2 standard-error band, over the run. Variables: tracks, png, c1t, dt, c2t.
#
# Each panel's y axis is scaled to what the estimate does over the second half of the rows
# (the errors and their bands, and the truth at 0, with 10 % margin), so that the converged
# estimate and its band are visible: at 0.05 % errors a fixed +-5 % axis drew flat lines.
# The earlier rows (a start transient of several percent) enter from beyond the top or
# bottom: the convergence shows as the band narrowing onto the truth. The ranges
# chosen are printed on stderr ("yrange c1: lo:hi"), which tests/daemon's demo_plot checks.
set datafile separator ","
set terminal pngcairo size 1000,800 noenhanced
set output png
set multiplot layout 3,1 title "vibidd on vibid-sim (paper example 1, Modbus TCP loopback): estimate / truth - 1, +-2 se"
set grid
set key top right box opaque
set ylabel "error [%]"
t0 = system(sprintf("grep -v '^#' '%s' | awk -F, 'NR==2{print $1}'", tracks)) + 0
set xlabel "time since the first row [s]"
# lo:hi of 100 (estimate / truth - 1) +- 200 se / truth over the second half of the rows
# (column col is the estimate, col + 1 its standard error; rows without an estimate skipped)
range_of(col, truth) = system(sprintf("grep -v '^#' '%s' | awk -F, -v c=%d -v tr=%.17g '" . \
    "NR > 1 && $c != \"\" && $c != \"nan\" && $(c + 1) != \"nan\" { n++; e[n] = 100 * ($c / tr - 1); s[n] = 200 * $(c + 1) / tr } " . \
    "END { lo = 0; hi = 0; for (i = int(n / 2) + 1; i <= n; i++) { if (e[i] - s[i] < lo) lo = e[i] - s[i]; " . \
    "if (e[i] + s[i] > hi) hi = e[i] + s[i] } m = 0.1 * (hi - lo); if (m <= 0) m = 1e-3; printf \"%%.6g:%%.6g\", lo - m, hi + m }'", \
    tracks, col, truth))
do for [p in "c1:3 d:5 c2:7"] {
    name = p[1:strstrt(p, ":") - 1]
    col = int(p[strstrt(p, ":") + 1:])
    truth = name eq "c1" ? c1t : (name eq "d" ? dt : c2t)
    r = range_of(col, truth)
    print sprintf("yrange %s: %s", name, r)
    eval "set yrange [" . r . "]"
    plot tracks every ::1 using ($1 - t0):(100 * (column(col) / truth - 1) - 200 * column(col + 1) / truth): \
                                (100 * (column(col) / truth - 1) + 200 * column(col + 1) / truth) \
             with filledcurves fillcolor "#c6dbef" title sprintf("%s: +-2 se", name), \
         '' every ::1 using ($1 - t0):(100 * (column(col) / truth - 1)) with lines linewidth 2 title "estimate", \
         0 with lines dashtype 2 linecolor "black" title "truth"
}
unset multiplot
