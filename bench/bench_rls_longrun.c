/* bench_rls_longrun.c: the full wind-up run of issue 2 (tests/lib/test_rls_windup.c is
 * the shortened CI version): forgetting 0.98, p = 4, an input that excites only now and
 * then, N updates (default 1e8).
 *
 * Usage: bench_rls_longrun [N]
 *
 * Schedule, repeated every 25000 samples: 1000 exciting samples (x ~ N(0, I)); 12000
 * samples with x = 0; 1000 exciting samples; 11000 samples along one constant
 * direction. y = x^T theta + 0.01 noise.
 *
 * Runs side by side on the same data:
 *   robust: Bierman UD form with the trace bound (trace_max = p / alpha = 4000),
 *   plain:  covariance form without guard.
 * Prints at 10 checkpoints and at the end: trace(P), min D (robust) or min diag(P)
 * (plain), the relative asymmetry of P read back, whether P passes Cholesky, the
 * largest trace seen, the Theta error at the end of the last exciting block, and the
 * number of updates the library refused (VIBID_E_NUMERICAL: the update would have
 * broken P; the estimator stays as it was). Exit status 1 if the robust form ever
 * failed (refusal, D <= 0, trace above the bound, P not PD), else 0. */
#include <vibid/rls.h>

#include "rls_check.h" /* tests/lib/support: the same PD and asymmetry checks as the CI test */
#include "test_rng.h"  /* tests/lib/support: the same reproducible random numbers */

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

enum { P_DIM = 4, CYCLE = 25000 };
static const double theta_true[P_DIM] = {2.0, -1.0, 0.5, 3.0};
static const double direction[P_DIM] = {1.0, 0.5, -0.25, 0.0};

typedef struct track {
    const char *name;
    vibid_rls *rls;
    long long refused, first_refused, first_not_pd, checks_not_pd;
    double max_trace, min_d, max_asym, theta_err;
} track;

static vibid_rls *make(vibid_rls_form form, vibid_rls_windup windup) {
    vibid_rls_config cfg;
    vibid_rls_config_init(&cfg, P_DIM, 1);
    cfg.form = form;
    cfg.forgetting = 0.98;
    cfg.alpha = 1e-3;
    cfg.windup = windup;
    cfg.trace_max = P_DIM / cfg.alpha;
    vibid_rls *rls = vibid_rls_create(&cfg);
    if (!rls) {
        fprintf(stderr, "vibid_rls_create: %s\n", vibid_last_error());
        exit(2);
    }
    return rls;
}

static void step(track *t, long long k, const double *x, double y) {
    if (vibid_rls_update(t->rls, x, &y) != VIBID_OK) {
        if (t->refused++ == 0) t->first_refused = k;
    }
    vibid_rls_stats st;
    vibid_rls_get_stats(t->rls, &st);
    if (!(st.trace_p <= t->max_trace)) t->max_trace = st.trace_p;
    if (!(st.min_d >= t->min_d)) t->min_d = st.min_d;
}

/* Reads P back and checks it; done every 997 updates (cheap against the update). */
static void check(track *t, long long k) {
    double P[P_DIM * P_DIM];
    vibid_rls_covariance(t->rls, P);
    if (!rls_check_is_pd(P, P_DIM)) {
        if (t->checks_not_pd++ == 0) t->first_not_pd = k;
    }
    const double a = rls_check_asymmetry(P, P_DIM);
    if (!(a <= t->max_asym)) t->max_asym = a;
}

static void report(const track *t, long long k) {
    vibid_rls_stats st;
    double P[P_DIM * P_DIM];
    vibid_rls_get_stats(t->rls, &st);
    vibid_rls_covariance(t->rls, P);
    printf("  %-7s k=%-11lld trace=%-10.4g minD=%-10.4g asym=%-9.3g PD=%d | max trace=%-10.4g min minD=%-10.4g "
           "max asym=%-9.3g not-PD checks=%lld (first %lld) refused=%lld (first %lld) theta err=%.3g\n",
           t->name, k, st.trace_p, st.min_d, rls_check_asymmetry(P, P_DIM), rls_check_is_pd(P, P_DIM), t->max_trace, t->min_d, t->max_asym,
           t->checks_not_pd, t->first_not_pd, t->refused, t->first_refused, t->theta_err);
}

int main(int argc, char **argv) {
    const long long n = argc > 1 ? atoll(argv[1]) : 100000000LL;
    if (n <= 0) {
        fprintf(stderr, "usage: %s [number of updates > 0]\n", argv[0]);
        return 2;
    }
    track tr[2] = {
        {"robust", make(VIBID_RLS_FORM_BIERMAN_UD, VIBID_RLS_WINDUP_TRACE_BOUND), 0, -1, -1, 0, 0.0, INFINITY, 0.0,
         NAN},
        {"plain", make(VIBID_RLS_FORM_COVARIANCE, VIBID_RLS_WINDUP_NONE), 0, -1, -1, 0, 0.0, INFINITY, 0.0, NAN},
    };
    printf("RLS wind-up run: p = %d, forgetting 0.98, alpha 1e-3, trace_max %g, %lld updates\n", P_DIM,
           P_DIM / 1e-3, n);
    test_rng r;
    test_rng_seed(&r, 2024);
    double x[P_DIM];
    const long long every = n >= 10 ? n / 10 : 1;
    for (long long k = 0; k < n; ++k) {
        const long long c = k % CYCLE;
        if (c < 1000 || (c >= 13000 && c < 14000)) {
            for (int i = 0; i < P_DIM; ++i) x[i] = test_rng_normal(&r);
        } else if (c < 13000) {
            memset(x, 0, sizeof x);
        } else {
            memcpy(x, direction, sizeof x);
        }
        double y = 0.01 * test_rng_normal(&r);
        for (int i = 0; i < P_DIM; ++i) y += x[i] * theta_true[i];
        for (int t = 0; t < 2; ++t) {
            step(&tr[t], k, x, y);
            if (k % 997 == 0 || c == 999 || c == 13999) check(&tr[t], k);
            if (c == 13999) {
                double th[P_DIM];
                vibid_rls_theta(tr[t].rls, th);
                tr[t].theta_err = 0.0;
                for (int i = 0; i < P_DIM; ++i) tr[t].theta_err = fmax(tr[t].theta_err, fabs(th[i] - theta_true[i]));
            }
        }
        if ((k + 1) % every == 0 || k + 1 == n) {
            for (int t = 0; t < 2; ++t) report(&tr[t], k + 1);
            fflush(stdout);
        }
    }
    const track *rb = &tr[0];
    const int robust_ok = rb->refused == 0 && rb->checks_not_pd == 0 && rb->min_d > 0.0 &&
                          rb->max_trace <= P_DIM / 1e-3 * (1.0 + 1e-12);
    printf("robust form: %s; plain form: %s\n", robust_ok ? "bounded, positive definite throughout" : "FAILED",
           tr[1].refused || tr[1].checks_not_pd ? "broke down (see refused / not-PD counts)" : "survived");
    for (int t = 0; t < 2; ++t) vibid_rls_destroy(tr[t].rls);
    return robust_ok ? 0 : 1;
}
