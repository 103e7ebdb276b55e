/* paper_example3_study.c: see paper_example3_study.h. */
#include "paper_example3_study.h"

#include <vibid/vibid.h>

#include <math.h>
#include <stdlib.h>
#include <string.h>

static uint64_t splitmix(uint64_t *s) {
    uint64_t z = (*s += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

void ex3_rng_seed(ex3_rng *g, uint64_t seed) {
    g->s = seed;
    g->has_spare = 0;
    g->spare = 0.0;
}

double ex3_rng_normal(ex3_rng *g) {
    if (g->has_spare) {
        g->has_spare = 0;
        return g->spare;
    }
    double u, v, q;
    do {
        u = 2.0 * ((double)(splitmix(&g->s) >> 11) * 0x1.0p-53) - 1.0;
        v = 2.0 * ((double)(splitmix(&g->s) >> 11) * 0x1.0p-53) - 1.0;
        q = u * u + v * v;
    } while (q >= 1.0 || q == 0.0);
    const double f = sqrt(-2.0 * log(q) / q);
    g->spare = v * f;
    g->has_spare = 1;
    return u * f;
}

const char *ex3_estimator_name(int est) {
    static const char *names[EX3_N_EST] = {"plain LS (differences)", "I/O form LS", "I/O form IV",
                                           "KF+RLS (paper), cold start", "KF+RLS, I/O start",
                                           "EKF, cold start", "EKF, I/O start"};
    return est >= 0 && est < EX3_N_EST ? names[est] : "?";
}

double ex3_var_x(const ex3_setup *s) {
    /* P = G P G^T + Q, G = [1 h; c d], Q = diag(0, h^2 Rw), by fixed-point iteration
     * (spectral radius 0.98: 4000 steps reach machine precision). */
    double p11 = 0, p12 = 0, p22 = 0;
    const double h = s->h, c = s->c, d = s->d;
    for (int i = 0; i < 4000; ++i) {
        const double n11 = p11 + 2 * h * p12 + h * h * p22;
        const double n12 = c * p11 + (d + h * c) * p12 + h * d * p22;
        const double n22 = c * c * p11 + 2 * c * d * p12 + d * d * p22 + h * h * s->Rw;
        p11 = n11;
        p12 = n12;
        p22 = n22;
    }
    return p11;
}

void ex3_setup_init(ex3_setup *s, double snr_db) {
    s->h = 0.05;
    s->c = -1.25;
    s->d = 0.9;
    s->Rw = 1.0;
    s->Rv = 0.0;
    if (snr_db >= 0.0) s->Rv = ex3_var_x(s) * pow(10.0, -snr_db / 10.0);
}

void ex3_simulate(const ex3_setup *s, ex3_rng *g, size_t N, double *z) {
    double x = 0.0, r = 0.0;
    const double sv = sqrt(s->Rv), sw = sqrt(s->Rw);
    for (size_t k = 0; k < N + 1000; ++k) { /* 1000 samples burn-in: 0.98^1000 ~ 2e-9 */
        if (k >= 1000) z[k - 1000] = x + sv * ex3_rng_normal(g);
        const double xn = x + s->h * r;
        const double rn = s->c * x + s->d * r + s->h * sw * ex3_rng_normal(g);
        x = xn;
        r = rn;
    }
}

static int plain_ls(const ex3_setup *s, const double *z, size_t N, double *c, double *d) {
    if (N < 5) return VIBID_E_INSUFFICIENT_DATA;
    const size_t n = N - 2;
    double *X = malloc(sizeof(double) * 2 * n), *Y = malloc(sizeof(double) * n);
    int st = VIBID_E_NO_MEMORY;
    vibid_lsq *lsq = vibid_lsq_create(2, 1);
    if (X && Y && lsq) {
        for (size_t k = 0; k < n; ++k) {
            X[k] = z[k];
            X[k + n] = (z[k + 1] - z[k]) / s->h;
            Y[k] = (z[k + 2] - z[k + 1]) / s->h;
        }
        double th[2];
        st = vibid_lsq_add_rows(lsq, n, X, Y, NULL);
        if (st == VIBID_OK) st = vibid_lsq_solve(lsq, th, NULL);
        if (st == VIBID_OK) {
            *c = th[0];
            *d = th[1];
        }
    }
    vibid_lsq_destroy(lsq);
    free(X);
    free(Y);
    return st;
}

/* I/O form estimate, then c, d (and their covariance, 2 x 2) from the polynomial. */
static int io_form(const ex3_setup *s, const double *z, size_t N, int iv, double *c, double *d, double *cov) {
    vibid_ioform_config cfg;
    vibid_ioform_config_init(&cfg, 2, 1, 0);
    cfg.method = iv ? VIBID_IOFORM_IV : VIBID_IOFORM_LS;
    double a[2], acov[4];
    int st = vibid_ioform_estimate(&cfg, z, NULL, N, a, acov, NULL, NULL);
    if (st != VIBID_OK) return st;
    double G[4] = {1.0, s->c * 0.8, s->h, s->d * 0.9}; /* start values for c, d */
    const unsigned char mask[4] = {0, 1, 0, 1};
    double gcov[4];
    st = vibid_ioform_recover_g(a, 2, G, mask, acov, gcov);
    if (st != VIBID_OK) return st;
    *c = G[1];
    *d = G[3];
    if (cov) memcpy(cov, gcov, sizeof gcov);
    return VIBID_OK;
}

static int kalman(const ex3_setup *s, const double *z, size_t N, int ekf, int io_start, double *c, double *d,
                  double *c_track, double *d_track) {
    vibid_kfrls_config cfg;
    vibid_kfrls_config_init(&cfg, 2, 1, 0);
    cfg.first_free_row = 1;
    cfg.method = ekf ? VIBID_KFRLS_EKF : VIBID_KFRLS_PAPER;
    const double U[2] = {1.0, 0.0};
    const double Rb[4] = {0.0, 0.0, 0.0, s->h * s->h * s->Rw};
    const double Rv = s->Rv;
    vibid_kfrls *kf = vibid_kfrls_create(&cfg, U, Rb, &Rv);
    if (!kf) return VIBID_E_INTERNAL;
    /* Cold start: 20 % / 11 % off, prior standard deviations 0.5 and 0.1. */
    double c0 = -1.0, d0 = 0.8;
    double P[4] = {0.25, 0.0, 0.0, 0.01};
    if (io_start) {
        double cc, dd, cov[4];
        if (io_form(s, z, N, s->Rv > 0.0, &cc, &dd, cov) == VIBID_OK && cov[0] > 0.0 && cov[3] > 0.0) {
            c0 = cc;
            d0 = dd;
            for (int i = 0; i < 4; ++i) P[i] = 10.0 * cov[i]; /* inflated: the data are used again */
        }
    }
    const double G0[4] = {1.0, c0, s->h, d0};
    const double x0[2] = {z[0], 0.0};
    /* S0: x known up to R_v, r from its stationary spread (var r ~ var x * |c| / h). */
    const double S0[4] = {Rv, 0.0, 0.0, ex3_var_x(s) * fabs(s->c) / s->h};
    int st = vibid_kfrls_start(kf, G0, NULL, x0, S0, P);
    if (c_track) {
        for (size_t k = 0; k < N; ++k) c_track[k] = d_track[k] = NAN;
    }
    double G[4] = {1.0, c0, s->h, d0};
    for (size_t k = 0; st == VIBID_OK && k + 1 < N; ++k) {
        st = vibid_kfrls_step(kf, NULL, &z[k + 1]);
        if (st == VIBID_OK && c_track) {
            vibid_kfrls_model(kf, G, NULL);
            c_track[k + 1] = G[1];
            d_track[k + 1] = G[3];
        }
    }
    if (st == VIBID_OK) {
        vibid_kfrls_model(kf, G, NULL);
        *c = G[1];
        *d = G[3];
    }
    vibid_kfrls_destroy(kf);
    return st;
}

int ex3_estimate(int est, const ex3_setup *s, const double *z, size_t N, double *c, double *d, double *c_track,
                 double *d_track) {
    switch (est) {
    case EX3_PLAIN_LS: return plain_ls(s, z, N, c, d);
    case EX3_IO_LS: return io_form(s, z, N, 0, c, d, NULL);
    case EX3_IO_IV: return io_form(s, z, N, 1, c, d, NULL);
    case EX3_KFRLS: return kalman(s, z, N, 0, 0, c, d, c_track, d_track);
    case EX3_KFRLS_IO: return kalman(s, z, N, 0, 1, c, d, c_track, d_track);
    case EX3_EKF: return kalman(s, z, N, 1, 0, c, d, c_track, d_track);
    case EX3_EKF_IO: return kalman(s, z, N, 1, 1, c, d, c_track, d_track);
    default: return VIBID_E_OUT_OF_RANGE;
    }
}

void ex3_monte_carlo(const ex3_setup *s, size_t N, int runs, uint64_t seed, unsigned mask, ex3_mc_result *res) {
    double sc[EX3_N_EST] = {0}, sc2[EX3_N_EST] = {0}, sd[EX3_N_EST] = {0}, sd2[EX3_N_EST] = {0};
    int ok[EX3_N_EST] = {0};
    memset(res, 0, sizeof *res);
    double *z = malloc(sizeof(double) * N);
    if (!z) return;
    ex3_rng g;
    ex3_rng_seed(&g, seed);
    for (int run = 0; run < runs; ++run) {
        ex3_simulate(s, &g, N, z);
        for (int e = 0; e < EX3_N_EST; ++e) {
            if (!(mask & (1u << e))) continue;
            double c = NAN, d = NAN;
            if (ex3_estimate(e, s, z, N, &c, &d, NULL, NULL) != 0 || !isfinite(c) || !isfinite(d)) {
                ++res->fails[e];
                continue;
            }
            const double ec = fabs(c / s->c - 1.0), ed = fabs(d / s->d - 1.0);
            sc[e] += ec;
            sc2[e] += ec * ec;
            sd[e] += ed;
            sd2[e] += ed * ed;
            ++ok[e];
        }
    }
    for (int e = 0; e < EX3_N_EST; ++e) {
        const double n = ok[e];
        if (n < 2) {
            res->mare_c[e] = res->mare_d[e] = res->se_c[e] = res->se_d[e] = NAN;
            continue;
        }
        res->mare_c[e] = sc[e] / n;
        res->mare_d[e] = sd[e] / n;
        res->se_c[e] = sqrt(fmax(0.0, (sc2[e] / n - res->mare_c[e] * res->mare_c[e]) / (n - 1)));
        res->se_d[e] = sqrt(fmax(0.0, (sd2[e] / n - res->mare_d[e] * res->mare_d[e]) / (n - 1)));
    }
    free(z);
}
