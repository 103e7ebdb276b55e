#include "rls_check.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

int rls_check_is_pd(const double *A, size_t n) {
    double *L = calloc(n * n, sizeof *L);
    if (!L) return 0;
    int pd = 1;
    for (size_t j = 0; j < n && pd; ++j) {
        double d = A[j + j * n];
        for (size_t k = 0; k < j; ++k) d -= L[j + k * n] * L[j + k * n];
        if (!(d > 0.0) || !isfinite(d)) {
            pd = 0;
            break;
        }
        L[j + j * n] = sqrt(d);
        for (size_t i = j + 1; i < n; ++i) {
            double s = A[j + i * n]; /* upper triangle: A(j, i) */
            for (size_t k = 0; k < j; ++k) s -= L[i + k * n] * L[j + k * n];
            L[i + j * n] = s / L[j + j * n];
        }
    }
    free(L);
    return pd;
}

double rls_check_asymmetry(const double *A, size_t n) {
    double amax = 0.0, dmax = 0.0;
    for (size_t j = 0; j < n; ++j)
        for (size_t i = 0; i < n; ++i) {
            const double a = fabs(A[i + j * n]), d = fabs(A[i + j * n] - A[j + i * n]);
            if (!(a <= amax)) amax = a; /* NaN propagates into amax */
            if (!(d <= dmax)) dmax = d;
        }
    return amax == 0.0 ? 0.0 : dmax / amax;
}

double rls_check_rel_diff(const double *a, const double *b, size_t n) {
    double bmax = 0.0, dmax = 0.0;
    for (size_t i = 0; i < n; ++i) {
        const double d = fabs(a[i] - b[i]);
        if (!(d <= dmax)) dmax = d;
        if (fabs(b[i]) > bmax) bmax = fabs(b[i]);
    }
    return bmax == 0.0 ? dmax : dmax / bmax;
}

void rls_snapshot_take(rls_snapshot *s, const vibid_rls *rls, size_t p, size_t q) {
    s->p = p;
    s->q = q;
    s->theta = calloc(p * q, sizeof(double));
    s->P = calloc(p * p, sizeof(double));
    s->sigma = calloc(q * q, sizeof(double));
    memset(&s->stats, 0, sizeof s->stats);
    vibid_rls_theta(rls, s->theta);
    vibid_rls_covariance(rls, s->P);
    s->sigma_status = (int)vibid_rls_residual_covariance(rls, s->sigma);
    vibid_rls_get_stats(rls, &s->stats);
}

int rls_snapshot_equal(const rls_snapshot *a, const rls_snapshot *b) {
    return a->p == b->p && a->q == b->q && memcmp(a->theta, b->theta, a->p * a->q * sizeof(double)) == 0 &&
           memcmp(a->P, b->P, a->p * a->p * sizeof(double)) == 0 &&
           memcmp(a->sigma, b->sigma, a->q * a->q * sizeof(double)) == 0 && a->sigma_status == b->sigma_status &&
           a->stats.n_samples == b->stats.n_samples &&
           memcmp(&a->stats.n_eff, &b->stats.n_eff, sizeof(double)) == 0 &&
           memcmp(&a->stats.trace_p, &b->stats.trace_p, sizeof(double)) == 0 &&
           memcmp(&a->stats.min_d, &b->stats.min_d, sizeof(double)) == 0 &&
           memcmp(&a->stats.last_forgetting, &b->stats.last_forgetting, sizeof(double)) == 0;
}

void rls_snapshot_free(rls_snapshot *s) {
    free(s->theta);
    free(s->P);
    free(s->sigma);
    s->theta = s->P = s->sigma = NULL;
}
