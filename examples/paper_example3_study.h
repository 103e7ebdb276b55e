/* paper_example3_study.h: the paper's example 3 (Bild 4, equations (4.3)) as a Monte Carlo
 * study, shared by examples/paper_example3.c (full study, table, tracks, plot) and the
 * fast test tests/kf/test_kf_example3.c.
 *
 *   x_{k+1} = x_k + h r_k,  r_{k+1} = c x_k + d r_k + h w_k,  z_k = x_k + v_k,
 *   w ~ N(0, R_w), v ~ N(0, R_v), true c = -1.25, d = 0.9, h = 0.05, R_w = 1.
 */
#ifndef PAPER_EXAMPLE3_STUDY_H
#define PAPER_EXAMPLE3_STUDY_H
#include <stddef.h>
#include <stdint.h>

typedef enum ex3_estimator {
    EX3_PLAIN_LS = 0, /* complete-observation LS on exact differences r_k = (z_{k+1} - z_k) / h */
    EX3_IO_LS,        /* input-output form LS, then c, d from the polynomial */
    EX3_IO_IV,        /* input-output form IV (delayed outputs as instruments) */
    EX3_KFRLS,        /* paper (3.16), cold start c0 = -1.0, d0 = 0.8 */
    EX3_KFRLS_IO,     /* paper (3.16), started from the I/O-form estimate of the record */
    EX3_EKF,          /* EKF on [x r c d], cold start */
    EX3_EKF_IO,       /* EKF started from the I/O-form estimate */
    EX3_N_EST
} ex3_estimator;

typedef struct ex3_setup {
    double h, c, d, Rw, Rv;
} ex3_setup;

typedef struct ex3_rng {
    uint64_t s;
    int has_spare;
    double spare;
} ex3_rng;

void ex3_rng_seed(ex3_rng *g, uint64_t seed);
double ex3_rng_normal(ex3_rng *g);

const char *ex3_estimator_name(int est);
/* Stationary variance of x (discrete Lyapunov equation). */
double ex3_var_x(const ex3_setup *s);
/* Setup with true values; snr_db < 0 for no measurement noise. */
void ex3_setup_init(ex3_setup *s, double snr_db);
/* N measurements z_0..z_{N-1}, stationary start (burn-in). */
void ex3_simulate(const ex3_setup *s, ex3_rng *g, size_t N, double *z);
/* Estimate c, d with estimator est from z. 0 on success; non-zero (a vibid_status) on
 * failure (e.g. divergence). If c_track / d_track are non-NULL (N entries) the
 * recursive estimators write their track (NaN elsewhere). */
int ex3_estimate(int est, const ex3_setup *s, const double *z, size_t N, double *c, double *d, double *c_track,
                 double *d_track);

typedef struct ex3_mc_result {
    double mare_c[EX3_N_EST], mare_d[EX3_N_EST]; /* mean |relative error| over successful runs */
    double se_c[EX3_N_EST], se_d[EX3_N_EST];     /* Monte Carlo standard error of those means */
    int fails[EX3_N_EST];
} ex3_mc_result;

/* Runs `runs` realisations at length N for the estimators whose bit is set in mask. */
void ex3_monte_carlo(const ex3_setup *s, size_t N, int runs, uint64_t seed, unsigned mask, ex3_mc_result *res);
#endif
