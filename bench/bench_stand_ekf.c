/* bench_stand_ekf.c: cost of one sample through the state-space estimator
 * (VIBID_ESTIMATOR_EKF, identify.h) on chains of 1, 2, 3 and 5 DOF (ground - m1 - ... - mn,
 * a measured force on m1, only the last mass's displacement measured, every spring and
 * damper unknown: p = 2 n), at 10 kHz. Beside it, in the same run, the yardstick: the
 * regression path (RLS, central differences) on the same chain with every displacement
 * measured, the estimator the daemon runs on fully measured stands; and the budget of a
 * 10 kHz stand (100 us per sample).
 *
 * Data: the true chain, exact discretisation (vibid_zoh) driven by a held random force,
 * with 0.1 % sensor noise. Timed: vibid_ident_push after the start window (1000
 * samples), best of 3; the start window's own cost (noise levels and the pass over the
 * window) separately, once; and one vibid_ident_estimate. Also printed: the largest
 * relative error at the end and whether the filter restarted after divergence.
 *
 * Usage: bench_stand_ekf [scale]  (scale multiplies the samples timed, default 1).
 * Prints a table; never fails on time. */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include <vibid/discretize.h>
#include <vibid/identify.h>
#include <vibid/model.h>

#define H 1e-4  /* 10 kHz */
#define MAXN 5

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static uint64_t rng = 0x9E3779B97F4A7C15ull;
static double uniform_pm1(void)
{
    rng ^= rng << 13;
    rng ^= rng >> 7;
    rng ^= rng << 17;
    return 2.0 * ((double)(rng >> 11) / 9007199254740992.0) - 1.0;
}

/* chain element values: spring i (node i to node i-1 or ground), damper i, mass i */
static double k_of(int i) { return 4e5 - 5e4 * i; }
static double d_of(int i) { return 40.0 - 5.0 * i; }
static double m_of(int i) { return 2.0 - 0.25 * i; }

/* The chain; all_measured: every displacement (the regression's stand), else the last
 * only. Nominal values 10 % off the truth (the start of the filter). */
static vibid_model *chain(int n, int all_measured)
{
    vibid_model *m = vibid_model_create();
    size_t node[MAXN];
    char name[16];
    for (int i = 0; i < n; i++) {
        snprintf(name, sizeof name, "m%d", i + 1);
        vibid_model_add_node(m, name, m_of(i), 0, &node[i]);
        if (all_measured || i == n - 1) vibid_model_set_measured(m, node[i], VIBID_MEASURE_DISPLACEMENT);
    }
    for (int i = 0; i < n; i++) {
        const size_t other = i == 0 ? VIBID_GROUND : node[i - 1];
        snprintf(name, sizeof name, "k%d", i + 1);
        vibid_model_add_element(m, name, VIBID_ELEMENT_SPRING, node[i], other, 1.1 * k_of(i), 1);
        snprintf(name, sizeof name, "d%d", i + 1);
        vibid_model_add_element(m, name, VIBID_ELEMENT_DAMPER, node[i], other, 0.9 * d_of(i), 1);
    }
    size_t in;
    vibid_model_add_input(m, "f", node[0], 1.0, 0, &in);
    vibid_model_set_hold(m, in, VIBID_HOLD_ZOH);
    if (vibid_model_finalize(m) != VIBID_OK) {
        fprintf(stderr, "bench_stand_ekf: %s\n", vibid_last_error());
        exit(1);
    }
    return m;
}

/* K samples of the true chain: channels in the model's order (node displacements, then
 * the force), row-major K x (n + 1) for all_measured, K x 2 otherwise. */
static double *simulate(int n, int all_measured, size_t K)
{
    const int nx = 2 * n;
    double A[4 * MAXN * MAXN] = {0}, B[2 * MAXN] = {0}, G[4 * MAXN * MAXN], Gam[2 * MAXN], x[2 * MAXN] = {0},
           xn[2 * MAXN];
    /* A = [0 I; -M^-1 C, -M^-1 D], column-major nx x nx */
    for (int i = 0; i < n; i++) {
        A[i + (n + i) * nx] = 1.0;
        for (int e = 0; e < n; e++) { /* element e joins node e and node e-1 (ground for e = 0) */
            const int a = e, b = e - 1;
            const double kk = k_of(e), dd = d_of(e);
            if (i == a) {
                A[n + i + a * nx] -= kk / m_of(i);
                A[n + i + (n + a) * nx] -= dd / m_of(i);
                if (b >= 0) {
                    A[n + i + b * nx] += kk / m_of(i);
                    A[n + i + (n + b) * nx] += dd / m_of(i);
                }
            } else if (i == b) {
                A[n + i + b * nx] -= kk / m_of(i);
                A[n + i + (n + b) * nx] -= dd / m_of(i);
                A[n + i + a * nx] += kk / m_of(i);
                A[n + i + (n + a) * nx] += dd / m_of(i);
            }
        }
    }
    B[n] = 1.0 / m_of(0);
    if (vibid_zoh((size_t)nx, 1, A, B, H, G, Gam) != VIBID_OK) {
        fprintf(stderr, "bench_stand_ekf: vibid_zoh: %s\n", vibid_last_error());
        exit(1);
    }
    const size_t nc = all_measured ? (size_t)n + 1 : 2;
    double *z = malloc(K * nc * sizeof(double));
    for (size_t k = 0; k < K; k++) {
        const double f = 200.0 * uniform_pm1();
        if (all_measured)
            for (int i = 0; i < n; i++) z[k * nc + (size_t)i] = x[i];
        else
            z[k * nc] = x[n - 1];
        z[k * nc + nc - 1] = f;
        for (int r = 0; r < nx; r++) {
            double acc = Gam[r] * f;
            for (int c = 0; c < nx; c++) acc += G[r + c * nx] * x[c];
            xn[r] = acc;
        }
        for (int r = 0; r < nx; r++) x[r] = xn[r];
    }
    /* 0.1 % sensor noise on the displacements (a noise-free channel is not a stand) */
    for (size_t c = 0; c + 1 < nc; c++) {
        double ss = 0.0;
        for (size_t k = 0; k < K; k++) ss += z[k * nc + c] * z[k * nc + c];
        const double sd = 1e-3 * sqrt(ss / (double)K) * sqrt(3.0); /* uniform_pm1 has std 1/sqrt(3) */
        for (size_t k = 0; k < K; k++) z[k * nc + c] += sd * uniform_pm1();
    }
    return z;
}

/* ns per sample of vibid_ident_push after `skip` samples, best of 3; *start_ms: the
 * first `skip` samples (once); *est_us: one vibid_ident_estimate. */
static double time_push(const vibid_model *m, const vibid_ident_config *cfg, const double *z, size_t nc, size_t K,
                        size_t skip, double *start_ms, double *est_us, unsigned long *restarts, double *max_err,
                        unsigned *flags)
{
    vibid_ident *id = vibid_ident_create(m, cfg);
    if (!id) {
        fprintf(stderr, "bench_stand_ekf: %s\n", vibid_last_error());
        exit(1);
    }
    double theta[2 * MAXN], se[2 * MAXN], best = 1e300, best_est = 1e300;
    *restarts = 0;
    for (int rep = 0; rep < 3; rep++) {
        vibid_ident_reset(id);
        double t0 = now_s();
        for (size_t k = 0; k < skip; k++) vibid_ident_push(id, z + k * nc);
        if (rep == 0) *start_ms = 1e3 * (now_s() - t0);
        t0 = now_s();
        for (size_t k = skip; k < K; k++)
            if (vibid_ident_push(id, z + k * nc) == VIBID_E_DIVERGED) ++*restarts;
        const double dt = (now_s() - t0) / (double)(K - skip);
        if (dt < best) best = dt;
        t0 = now_s();
        const vibid_status es = vibid_ident_estimate(id, theta, se, NULL);
        const double de = now_s() - t0;
        vibid_ident_quality q;
        *flags = vibid_ident_get_quality(id, &q, NULL) == VIBID_OK ? q.flags : ~0u;
        if (de < best_est) best_est = de;
        /* unknowns in the model's order: k1, d1, k2, d2, ... */
        size_t nc_, p;
        vibid_ident_dims(id, &nc_, &p);
        *max_err = es == VIBID_OK ? 0.0 : HUGE_VAL;
        for (size_t i = 0; i < p && es == VIBID_OK; i++) {
            const double truth = i % 2 ? d_of((int)i / 2) : k_of((int)i / 2);
            *max_err = fmax(*max_err, fabs(theta[i] / truth - 1.0));
        }
    }
    vibid_ident_destroy(id);
    *est_us = 1e6 * best_est;
    return 1e9 * best;
}

int main(int argc, char **argv)
{
    const double scale = argc > 1 && atof(argv[1]) > 0 ? atof(argv[1]) : 1.0;
    const size_t skip = 1000, K = skip + (size_t)(20000 * scale);
    printf("10 kHz: budget 100000 ns per sample. Chains ground - m1 - ... - mn, force on m1, p = 2 n unknowns.\n");
    printf("%-6s %-52s %11s %7s %9s %8s %9s %10s\n", "n DOF", "estimator (channels)", "ns/sample", "ratio", "start ms",
           "est. us", "x 10 kHz", "max err %");
    const int dofs[4] = {1, 2, 3, 5};
    for (int t = 0; t < 4; t++) {
        const int n = dofs[t];
        double start_ms, est_us, st2, est2, err, err2;
        unsigned long restarts, r2;
        unsigned fl, fl2;
        vibid_model *full = chain(n, 1), *end = chain(n, 0);
        double *zf = simulate(n, 1, K), *ze = simulate(n, 0, K);
        vibid_ident_config rls, ekf;
        vibid_ident_config_init(&rls, H);
        rls.estimator = VIBID_ESTIMATOR_RLS;
        rls.difference_order = 2;
        vibid_ident_config_init(&ekf, H); /* the automatic choice for n > 1; forced for n = 1 */
        ekf.estimator = VIBID_ESTIMATOR_EKF;
        const double t_rls = time_push(full, &rls, zf, (size_t)n + 1, K, skip, &st2, &est2, &r2, &err2, &fl2);
        const double t_ekf = time_push(end, &ekf, ze, 2, K, skip, &start_ms, &est_us, &restarts, &err, &fl);
        char label[96];
        snprintf(label, sizeof label, "RLS, central differences (all %d displacements)", n);
        printf("%-6d %-52s %11.0f %7s %9.1f %8.1f %9.1f %10.3f\n", n, label, t_rls, "1.00", st2, est2, 1e5 / t_rls,
               100 * err2);
        printf("%-6d %-52s %11.0f %7.1f %9.1f %8.1f %9.1f %10.3f%s%s\n", n, "EKF on the physical model (x_n only)", t_ekf,
               t_ekf / t_rls, start_ms, est_us, 1e5 / t_ekf, 100 * err,
               fl & VIBID_QUALITY_SE_INVALID ? "  flagged U" : "", restarts ? "  (restarted after divergence)" : "");
        free(zf);
        free(ze);
        vibid_model_destroy(full);
        vibid_model_destroy(end);
    }
    printf("x 10 kHz: how many times real time one core runs the estimator alone at 10 kHz. max err: largest\n"
           "relative error of the unknowns at the end (2 s of data; the RLS runs without a pre-filter on\n"
           "noisy data and is biased: it is here for the cost, not the accuracy). flagged U: the estimate's\n"
           "error bars are marked as not valid (identify.h: NIS, drift check).\n");
    return 0;
}
