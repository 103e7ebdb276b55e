# Tracks of the loopback demo: relative error of each estimate against the truth, with
# the +-2 standard-error band, over the run. Variables: tracks, png, c1t, dt, c2t.
set datafile separator ","
set terminal pngcairo size 1000,800 noenhanced
set output png
set multiplot layout 3,1 title "vibidd on vibid-sim (paper example 1, Modbus TCP loopback): estimate / truth - 1"
set grid
set ylabel "%"
t0 = system(sprintf("grep -v '^#' %s | awk -F, 'NR==2{print $1}'", tracks)) + 0
set xlabel "time [s]"
set yrange [-5:5]
plot tracks every ::1 using ($1-t0):(100*($3/c1t-1)):(200*$4/c1t) with yerrorlines title "c1"
plot tracks every ::1 using ($1-t0):(100*($5/dt-1)):(200*$6/dt) with yerrorlines title "d"
plot tracks every ::1 using ($1-t0):(100*($7/c2t-1)):(200*$8/c2t) with yerrorlines title "c2"
unset multiplot
