# paper_example3.gp: parameter tracks of example 3 (like the paper's Bild 4): c and d
# against the step k for KF+RLS (paper) and the EKF, noise-free and at 20 dB SNR.
# Variables (gnuplot -e): csv (input from paper_example3), png (output).
set datafile separator ","
set terminal pngcairo size 1200,800 noenhanced font ",10"
set output png
set multiplot layout 2,1
set grid
set xlabel "k (samples)"
set key outside right
set ylabel "c"
set yrange [-2:0]
plot csv using 1:2 with lines title "KF+RLS", csv using 1:4 with lines title "EKF", \
     csv using 1:6 with lines title "KF+RLS 20 dB", csv using 1:8 with lines title "EKF 20 dB", \
     -1.25 with lines lc rgb "black" dt 2 title "true"
set ylabel "d"
set yrange [0.6:1.1]
plot csv using 1:3 with lines title "KF+RLS", csv using 1:5 with lines title "EKF", \
     csv using 1:7 with lines title "KF+RLS 20 dB", csv using 1:9 with lines title "EKF 20 dB", \
     0.9 with lines lc rgb "black" dt 2 title "true"
unset multiplot
