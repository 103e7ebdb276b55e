/* paper_example3.c: the paper's example 3 (Bild 4, equations (4.3)): one-mass oscillator
 * with white random excitation, only the position measured.
 *
 *   x_{k+1} = x_k + h r_k,  r_{k+1} = c x_k + d r_k + h w_k,  z_k = x_k (+ v_k)
 *
 * True c = -1.25, d = 0.9. h = 0.05 s: the discrete poles 0.95 +- 0.245i (|z| = 0.981)
 * correspond to a continuous oscillator with omega_n = sqrt(-c / h) = 5 rad/s (0.8 Hz)
 * and zeta = (1 - d) / (2 h omega_n) = 0.2, sampled 25 times per period: stable and well
 * sampled. R_w = 1: the problem is linear, so the scale of w does not change any
 * relative error; R_v = var(x) / 100 gives 20 dB SNR.
 *
 * Monte Carlo: mean absolute relative error of c and d (and its Monte Carlo standard
 * error) for every estimator, N = 100, 200, 500, 1000, 5000, without and with noise.
 * Then one realisation (N = 1000) as parameter tracks in example3_tracks.csv and, if
 * gnuplot is installed, example3_tracks.png (like Bild 4).
 *
 * Usage: paper_example3 [outdir [runs]]   (runs default 500)
 */
#include "paper_example3_study.h"

#include <vibid/vibid.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>

int main(int argc, char **argv) {
    const char *outdir = argc > 1 ? argv[1] : ".";
    const int runs = argc > 2 ? atoi(argv[2]) : 500;
    if (runs < 2) {
        fprintf(stderr, "runs must be >= 2\n");
        return 2;
    }
    const size_t Ns[] = {100, 200, 500, 1000, 5000};
    const double snrs[] = {-1.0, 20.0};
    printf("Example 3 (4.3): h = 0.05, c = -1.25, d = 0.9, R_w = 1; %d realisations per cell.\n", runs);
    printf("Mean absolute relative error in %% (+- Monte Carlo standard error); paper KF+RLS: c 16 %% / 11 %%, "
           "d 3.1 %% / 2.8 %% at N = 100 / 200.\n");
    for (int si = 0; si < 2; ++si) {
        ex3_setup s;
        ex3_setup_init(&s, snrs[si]);
        printf("\n%s (R_v = %.4g, var x = %.4g)\n", si == 0 ? "noise-free z = x" : "20 dB SNR", s.Rv, ex3_var_x(&s));
        printf("%-28s %6s %16s %16s %6s\n", "estimator", "N", "c err %", "d err %", "fails");
        for (int e = 0; e < EX3_N_EST; ++e) {
            for (size_t ni = 0; ni < sizeof Ns / sizeof Ns[0]; ++ni) {
                ex3_mc_result r;
                ex3_monte_carlo(&s, Ns[ni], runs, 1000u + 17u * ni + 7919u * (unsigned)si, 1u << e, &r);
                printf("%-28s %6zu %8.2f +- %5.2f %8.2f +- %5.2f %6d\n", ex3_estimator_name(e), Ns[ni],
                       100 * r.mare_c[e], 100 * r.se_c[e], 100 * r.mare_d[e], 100 * r.se_d[e], r.fails[e]);
                fflush(stdout);
            }
        }
    }

    /* Tracks of one realisation, N = 1000, like Bild 4. */
    enum { NT = 1000 };
    static double z[NT], tr[2][4][NT];
    const int track_est[2] = {EX3_KFRLS, EX3_EKF};
    for (int si = 0; si < 2; ++si) {
        ex3_setup s;
        ex3_setup_init(&s, snrs[si]);
        ex3_rng g;
        ex3_rng_seed(&g, 42);
        ex3_simulate(&s, &g, NT, z);
        for (int t = 0; t < 2; ++t) {
            double c, d;
            int st = ex3_estimate(track_est[t], &s, z, NT, &c, &d, tr[si][2 * t], tr[si][2 * t + 1]);
            printf("track %s %s: c = %.4f, d = %.4f (status %d)\n", si ? "20dB" : "noise-free",
                   ex3_estimator_name(track_est[t]), c, d, st);
        }
    }
    char path[1024];
    snprintf(path, sizeof path, "%s/example3_tracks.csv", outdir);
    FILE *csv = fopen(path, "w");
    if (!csv) {
        perror(path);
        return 1;
    }
    fprintf(csv, "k,c_kfrls,d_kfrls,c_ekf,d_ekf,c_kfrls_20dB,d_kfrls_20dB,c_ekf_20dB,d_ekf_20dB\n");
    for (int k = 1; k < NT; ++k) {
        fprintf(csv, "%d", k);
        for (int si = 0; si < 2; ++si)
            for (int j = 0; j < 4; ++j) fprintf(csv, ",%.6g", tr[si][j][k]);
        fprintf(csv, "\n");
    }
    fclose(csv);
    printf("tracks: %s\n", path);
    char cmd[4096];
    snprintf(cmd, sizeof cmd,
             "command -v gnuplot >/dev/null 2>&1 && gnuplot -e \"csv='%s/example3_tracks.csv'; "
             "png='%s/example3_tracks.png'\" '%s'",
             outdir, outdir, VIBID_EXAMPLES_DIR "/paper_example3.gp");
    if (system(cmd) != 0)
        printf("(gnuplot not run: no plot)\n");
    else
        printf("plot: %s/example3_tracks.png\n", outdir);
    return 0;
}
