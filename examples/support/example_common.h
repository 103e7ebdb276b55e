/* example_common.h: what the paper's example programs share: the two-mass stand of
 * Bild 2 / (4.2), running one identification case against N, and the CSV of the tracks. */
#ifndef EXAMPLE_COMMON_H
#define EXAMPLE_COMMON_H

#include <stdio.h>
#include <vibid/vibid.h>

/* The stand of the paper's examples 1 and 2: nodes m1, m2 (known masses), elements
 * c1 (spring m1-m2), d (damper m1-m2), c2 (spring m2-base) and, when cubic_eps != 0,
 * eps (cubic spring m2-base); unknowns c1, d, c2 (, eps) in that order with the given
 * nominal (true) values. Displacements of m1, m2 and the base are measured. */
vibid_model *example_two_mass_model(double m1, double m2, double c1, double d, double c2, double cubic_eps,
                                    vibid_discretization disc);

typedef struct example_case {
    const char *name;          /* CSV/plot key, e.g. "noisy_cd_ls" */
    vibid_discretization disc;
    vibid_estimator estimator;
    double prefilter_hz;
    size_t iv_lag;
    int noisy;                 /* 1: the record with 1 % noise on every channel */
    int held;                  /* 1: the record with the base held over each interval (ZOH) */
} example_case;

/* Runs one case on a record (n_samples x n_channels, column-major), estimating at each
 * of the n_checkpoints sample counts; prints a table row per checkpoint and appends
 * CSV rows "case,N,<param>,<param>_se..." to csv. truth: true values (p).
 * mean_abs_rel_out (p, may be NULL): |estimate - truth| / |truth| at the last checkpoint. */
int example_run_case(const example_case *c, const vibid_model *model, double h, const double *record,
                     size_t n_samples, const size_t *checkpoints, size_t n_checkpoints, const double *truth, FILE *csv,
                     double *rel_err_out);

#endif
