# plot_tracks.gp: parameter tracks against the number of samples N, like the paper's
# Bild 2 and 3, one panel per parameter, estimate divided by the true value.
# Variables (set with gnuplot -e): csv (input, "case,N,p1,p1_se,p2,p2_se,..."),
# png (output), params (space-separated parameter names), truths (true values, same order).
set datafile separator ","
set terminal pngcairo size 1400,420*words(params) noenhanced font ",10"
set output png
cases = system(sprintf("tail -n +2 '%s' | cut -d, -f1 | uniq | tr '\\n' ' '", csv))
set multiplot layout words(params),1
set logscale x
set xlabel "N (samples)"
set grid
set key outside right
set yrange [0.5:1.5]
do for [i=1:words(params)] {
  t = word(truths, i) + 0.0
  set ylabel sprintf("%s / true (%g)", word(params, i), t)
  col = 3 + 2 * (i - 1)
  plot for [c in cases] csv using (strcol(1) eq c ? $2 : NaN):(strcol(1) eq c ? column(col) / t : NaN) \
       with linespoints title c, 1 with lines lc rgb "black" dt 2 notitle
}
unset multiplot
