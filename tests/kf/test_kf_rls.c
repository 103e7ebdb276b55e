/* test_kf_rls.c: input-output form (known answers, modes with delta-method errors,
 * recovery of G) and the joint state/parameter estimators (SPD of S over a long run, NaN
 * measurement, missing sample, divergence, bad arguments, known inputs). */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <vibid/vibid.h>

#include "paper_example3_study.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static const double kPi = 3.14159265358979323846;

/* ---- input-output form ---------------------------------------------------------- */

/* (4.3) with a known input on r: G = [1 h; c d], H = [0; h]. adj(zI - G) = z I + C0 with
 * C0 = [-d h; c -1], so U C1 H = 0 and U C0 H = h^2, a1 = -(1 + d), a0 = d - h c.
 * Noise-free data satisfy the I/O equation exactly: LS must return these to rounding. */
static void test_ioform_known_answer(void **state) {
    (void)state;
    const double h = 0.05, c = -1.25, d = 0.9;
    enum { N = 400 };
    double z[N], u[N];
    ex3_rng g;
    ex3_rng_seed(&g, 1);
    double x = 0.1, r = 0.0;
    for (int k = 0; k < N; ++k) {
        u[k] = ex3_rng_normal(&g);
        z[k] = x;
        const double xn = x + h * r, rn = c * x + d * r + h * u[k];
        x = xn;
        r = rn;
    }
    vibid_ioform_config cfg;
    vibid_ioform_config_init(&cfg, 2, 1, 1);
    double a[2], acov[4], ucih[2], s2;
    assert_int_equal(vibid_ioform_estimate(&cfg, z, u, N, a, acov, ucih, &s2), VIBID_OK);
    assert_true(fabs(a[1] + (1 + d)) < 1e-9);
    assert_true(fabs(a[0] - (d - h * c)) < 1e-9);
    assert_true(fabs(ucih[0] - h * h) < 1e-9); /* i = 0 */
    assert_true(fabs(ucih[1]) < 1e-9);         /* i = 1 */
    assert_true(s2 < 1e-20);
    /* IV on exact data is exact too. */
    cfg.method = VIBID_IOFORM_IV;
    assert_int_equal(vibid_ioform_estimate(&cfg, z, u, N, a, NULL, ucih, NULL), VIBID_OK);
    assert_true(fabs(a[1] + (1 + d)) < 1e-8 && fabs(a[0] - (d - h * c)) < 1e-8);

    /* Bad arguments. */
    assert_int_equal(vibid_ioform_estimate(NULL, z, u, N, a, NULL, NULL, NULL), VIBID_E_NULL_ARGUMENT);
    assert_int_equal(vibid_ioform_estimate(&cfg, z, NULL, N, a, NULL, NULL, NULL), VIBID_E_NULL_ARGUMENT);
    assert_int_equal(vibid_ioform_estimate(&cfg, z, u, 5, a, NULL, NULL, NULL), VIBID_E_INSUFFICIENT_DATA);
    cfg.iv_lags = 1;
    assert_int_equal(vibid_ioform_estimate(&cfg, z, u, N, a, NULL, NULL, NULL), VIBID_E_OUT_OF_RANGE);
    cfg.method = VIBID_IOFORM_LS;
    z[7] = NAN;
    assert_int_equal(vibid_ioform_estimate(&cfg, z, u, N, a, NULL, NULL, NULL), VIBID_E_NONFINITE);
    /* No excitation at all: all-zero data cannot identify anything. */
    memset(z, 0, sizeof z);
    memset(u, 0, sizeof u);
    assert_int_equal(vibid_ioform_estimate(&cfg, z, u, N, a, NULL, NULL, NULL), VIBID_E_NOT_IDENTIFIABLE);
}

/* Recursive I/O form: vibid_ioform_regressor + vibid_rls (alpha 1e-9) reproduces the
 * batch LS of the same equations (the alpha prior changes a by ~alpha / (N var z), far
 * below the 1e-6 relative tolerance). */
static void test_ioform_recursive(void **state) {
    (void)state;
    ex3_setup s;
    ex3_setup_init(&s, 20.0);
    enum { N = 2000 };
    double z[N];
    ex3_rng g;
    ex3_rng_seed(&g, 2);
    ex3_simulate(&s, &g, N, z);
    vibid_ioform_config cfg;
    vibid_ioform_config_init(&cfg, 2, 1, 0);
    double a[2];
    assert_int_equal(vibid_ioform_estimate(&cfg, z, NULL, N, a, NULL, NULL, NULL), VIBID_OK);
    vibid_rls_config rc;
    vibid_rls_config_init(&rc, 2, 1);
    rc.alpha = 1e-9;
    vibid_rls *rls = vibid_rls_create(&rc);
    assert_non_null(rls);
    double x[2], y[1], th[2];
    for (int k = 0; k + 2 < N; ++k) {
        assert_int_equal(vibid_ioform_regressor(&cfg, &z[k], NULL, x, y), VIBID_OK);
        assert_int_equal(vibid_rls_update(rls, x, y), VIBID_OK);
    }
    vibid_rls_theta(rls, th);
    assert_true(fabs(th[0] - a[0]) < 1e-6 * fabs(a[0]));
    assert_true(fabs(th[1] - a[1]) < 1e-6 * fabs(a[1]));
    vibid_rls_destroy(rls);
    const double zn[3] = {0.1, NAN, 0.2};
    assert_int_equal(vibid_ioform_regressor(&cfg, zn, NULL, x, y), VIBID_E_NONFINITE);
    cfg.n_inputs = 1;
    assert_int_equal(vibid_ioform_regressor(&cfg, z, NULL, x, y), VIBID_E_NULL_ARGUMENT);
}

/* Modes: a 0.8 Hz, zeta = 0.2 pole pair sampled at h = 0.05 comes back exactly; the
 * delta-method standard errors match finite differences of the root map. */
static void test_ioform_modes(void **state) {
    (void)state;
    const double h = 0.05, f0 = 0.8, z0 = 0.2, w = 2 * kPi * f0;
    const double sr = -z0 * w, si = w * sqrt(1 - z0 * z0);
    const double mag = exp(sr * h);
    double a[2] = {mag * mag, -2 * mag * cos(si * h)};
    double f[2], zt[2], fse[2], zse[2];
    size_t nm = 0;
    const double eps = 1e-7;
    double acov[4] = {eps * eps, 0, 0, 0};
    assert_int_equal(vibid_ioform_modes(a, acov, 2, h, f, zt, fse, zse, &nm), VIBID_OK);
    assert_int_equal(nm, 1);
    assert_true(fabs(f[0] - f0) < 1e-12);
    assert_true(fabs(zt[0] - z0) < 1e-12);
    /* Perturb a_0 by eps: the change of f, zeta must equal the linearised standard error
     * to first order (relative 1e-4 at this eps). */
    double ap[2] = {a[0] + eps, a[1]}, f2[2], zt2[2];
    size_t nm2 = 0;
    assert_int_equal(vibid_ioform_modes(ap, NULL, 2, h, f2, zt2, NULL, NULL, &nm2), VIBID_OK);
    assert_true(fabs(fabs(f2[0] - f[0]) - fse[0]) < 1e-4 * fse[0]);
    assert_true(fabs(fabs(zt2[0] - zt[0]) - zse[0]) < 1e-4 * zse[0]);
    /* Double root: no delta method. */
    double ad[2] = {0.25, -1.0};
    assert_int_equal(vibid_ioform_modes(ad, acov, 2, h, f, zt, fse, zse, &nm), VIBID_E_NUMERICAL);
    assert_int_equal(vibid_ioform_modes(a, NULL, 2, 0.0, f, zt, NULL, NULL, &nm), VIBID_E_OUT_OF_RANGE);
}

static void test_ioform_recover_g(void **state) {
    (void)state;
    const double h = 0.05, c = -1.25, d = 0.9;
    const double a[2] = {d - h * c, -(1 + d)};
    double G[4] = {1.0, -1.0, h, 0.8};
    const unsigned char mask[4] = {0, 1, 0, 1};
    assert_int_equal(vibid_ioform_recover_g(a, 2, G, mask, NULL, NULL), VIBID_OK);
    assert_true(fabs(G[1] - c) < 1e-10 && fabs(G[3] - d) < 1e-10);
    assert_true(G[0] == 1.0 && G[2] == h);
    /* Covariance by the delta method: c = (d - a0)/h, d = -a1 - 1, so with
     * Cov(a) = diag(s0, s1): var d = s1, var c = (s0 + s1) / h^2, cov(c, d) = s1 / h. */
    const double acov[4] = {1e-6, 0, 0, 4e-6};
    double gcov[4];
    assert_int_equal(vibid_ioform_recover_g(a, 2, G, mask, acov, gcov), VIBID_OK);
    assert_true(fabs(gcov[3] - 4e-6) < 1e-10);
    assert_true(fabs(gcov[0] - 5e-6 / (h * h)) < 1e-8);
    assert_true(fabs(gcov[1] - 4e-6 / h) < 1e-9);
    /* G(0,1) and G(1,0) enter the polynomial only through their product: not identifiable. */
    double G2[4] = {1.0, -1.0, h, 0.9};
    const unsigned char mask2[4] = {0, 1, 1, 0};
    assert_int_equal(vibid_ioform_recover_g(a, 2, G2, mask2, NULL, NULL), VIBID_E_NOT_IDENTIFIABLE);
    /* More free entries than coefficients. */
    const unsigned char mask3[4] = {1, 1, 0, 1};
    assert_int_equal(vibid_ioform_recover_g(a, 2, G2, mask3, NULL, NULL), VIBID_E_DIMENSION);
}

/* ---- joint state and parameter estimation ---------------------------------------- */

typedef struct fixture {
    ex3_setup s;
    vibid_kfrls *kf;
} fixture;

static vibid_kfrls *make_kf(const ex3_setup *s, vibid_kfrls_method method, double state_limit) {
    vibid_kfrls_config cfg;
    vibid_kfrls_config_init(&cfg, 2, 1, 0);
    cfg.first_free_row = 1;
    cfg.method = method;
    cfg.state_limit = state_limit;
    const double U[2] = {1.0, 0.0};
    const double Rb[4] = {0.0, 0.0, 0.0, s->h * s->h * s->Rw};
    vibid_kfrls *kf = vibid_kfrls_create(&cfg, U, Rb, &s->Rv);
    assert_non_null(kf);
    const double G0[4] = {1.0, -1.0, s->h, 0.8};
    const double S0[4] = {s->Rv, 0, 0, 0.03};
    const double P[4] = {0.25, 0, 0, 0.01};
    assert_int_equal(vibid_kfrls_start(kf, G0, NULL, NULL, S0, P), VIBID_OK);
    return kf;
}

/* Is the symmetric 2 x 2 S positive definite? */
static int spd2(const double *S) { return S[0] > 0 && S[3] > 0 && S[0] * S[3] - S[1] * S[2] > 0 && S[1] == S[2]; }

/* S stays symmetric positive definite over 20000 steps (R_v > 0), for both methods, and
 * the estimates end close to the truth (the run is long: 1 % on d, 5 % on c is about
 * 5 standard errors at N = 20000). */
static void test_long_run_spd(void **state) {
    (void)state;
    ex3_setup s;
    ex3_setup_init(&s, 20.0);
    enum { N = 20000 };
    double *z = malloc(sizeof(double) * N);
    assert_non_null(z);
    ex3_rng g;
    ex3_rng_seed(&g, 3);
    ex3_simulate(&s, &g, N, z);
    for (int m = 0; m < 2; ++m) {
        vibid_kfrls *kf = make_kf(&s, m ? VIBID_KFRLS_EKF : VIBID_KFRLS_PAPER, 1e12);
        double S[4], G[4];
        for (int k = 1; k < N; ++k) {
            assert_int_equal(vibid_kfrls_step(kf, NULL, &z[k]), VIBID_OK);
            if (k % 97 == 0) {
                assert_int_equal(vibid_kfrls_state(kf, NULL, S), VIBID_OK);
                assert_true(spd2(S));
            }
        }
        vibid_kfrls_model(kf, G, NULL);
        assert_true(fabs(G[1] / s.c - 1) < 0.05);
        assert_true(fabs(G[3] / s.d - 1) < 0.01);
        double se[2];
        assert_int_equal(vibid_kfrls_param_stderr(kf, se), VIBID_OK);
        assert_true(se[0] > 0 && se[0] < 0.1 && se[1] > 0 && se[1] < 0.02);
        vibid_kfrls_stats st;
        vibid_kfrls_get_stats(kf, &st);
        assert_true(st.n_steps == N - 1 && st.diverged == 0);
        /* A consistent filter has NIS ~ 1; 0.5..2 allows the ~50-step averaging spread. */
        assert_true(st.nis_avg > 0.5 && st.nis_avg < 2.0);
        vibid_kfrls_destroy(kf);
    }
    free(z);
}

typedef struct snap {
    double x[2], S[4], G[4];
    vibid_kfrls_stats st;
} snap;

static void take(const vibid_kfrls *kf, snap *sn) {
    memset(sn, 0, sizeof *sn);
    vibid_kfrls_state(kf, sn->x, sn->S);
    vibid_kfrls_model(kf, sn->G, NULL);
    vibid_kfrls_get_stats(kf, &sn->st);
}

static void assert_same(const snap *a, const snap *b) {
    assert_memory_equal(a->x, b->x, sizeof a->x);
    assert_memory_equal(a->S, b->S, sizeof a->S);
    assert_memory_equal(a->G, b->G, sizeof a->G);
    assert_true(a->st.n_steps == b->st.n_steps && a->st.nis_avg == b->st.nis_avg);
}

static void test_nan_and_missing(void **state) {
    (void)state;
    ex3_setup s;
    ex3_setup_init(&s, 20.0);
    double z[200];
    ex3_rng g;
    ex3_rng_seed(&g, 5);
    ex3_simulate(&s, &g, 200, z);
    for (int m = 0; m < 2; ++m) {
        vibid_kfrls *kf = make_kf(&s, m ? VIBID_KFRLS_EKF : VIBID_KFRLS_PAPER, 1e12);
        for (int k = 1; k < 100; ++k) assert_int_equal(vibid_kfrls_step(kf, NULL, &z[k]), VIBID_OK);
        snap a, b;
        take(kf, &a);
        /* NaN / Inf: rejected, nothing changes. */
        const double bad[2] = {NAN, INFINITY};
        for (int i = 0; i < 2; ++i) {
            assert_int_equal(vibid_kfrls_step(kf, NULL, &bad[i]), VIBID_E_NONFINITE);
            assert_true(strstr(vibid_last_error(), "NaN") != NULL);
            take(kf, &b);
            assert_same(&a, &b);
        }
        /* Missing sample: pure time update x = G x, S = G S G^T + R_b, model unchanged. */
        assert_int_equal(vibid_kfrls_step(kf, NULL, NULL), VIBID_OK);
        take(kf, &b);
        const double h = s.h, c = a.G[1], d = a.G[3];
        const double xp0 = a.x[0] + h * a.x[1], xp1 = c * a.x[0] + d * a.x[1];
        assert_true(fabs(b.x[0] - xp0) <= 1e-15 * (fabs(xp0) + 1e-300) + 1e-18);
        assert_true(fabs(b.x[1] - xp1) <= 1e-14 * fabs(xp1) + 1e-18);
        /* G S G^T + R_b, elementwise (G = [1 h; c d]). */
        const double s11 = a.S[0], s12 = a.S[2], s22 = a.S[3];
        const double e11 = s11 + 2 * h * s12 + h * h * s22;
        const double e12 = c * s11 + (d + h * c) * s12 + h * d * s22;
        const double e22 = c * c * s11 + 2 * c * d * s12 + d * d * s22 + h * h * s.Rw;
        if (m == 0) { /* PAPER: exactly the Kalman time update */
            assert_true(fabs(b.S[0] - e11) < 1e-12 * e11);
            assert_true(fabs(b.S[2] - e12) < 1e-12 * fabs(e12) + 1e-18);
            assert_true(fabs(b.S[3] - e22) < 1e-12 * e22);
        } else { /* EKF: the state block also carries parameter-uncertainty terms */
            assert_true(spd2(b.S));
        }
        assert_memory_equal(a.G, b.G, sizeof a.G);
        assert_true(b.st.n_missing == 1 && b.st.n_steps == a.st.n_steps + 1);
        /* And measurements continue normally afterwards. */
        for (int k = 101; k < 200; ++k) assert_int_equal(vibid_kfrls_step(kf, NULL, &z[k]), VIBID_OK);
        vibid_kfrls_destroy(kf);
    }
}

static void test_divergence(void **state) {
    (void)state;
    ex3_setup s;
    ex3_setup_init(&s, 20.0);
    double z[300];
    ex3_rng g;
    ex3_rng_seed(&g, 7);
    ex3_simulate(&s, &g, 300, z);
    for (int m = 0; m < 2; ++m) {
        vibid_kfrls *kf = make_kf(&s, m ? VIBID_KFRLS_EKF : VIBID_KFRLS_PAPER, 1e12);
        for (int k = 1; k < 100; ++k) assert_int_equal(vibid_kfrls_step(kf, NULL, &z[k]), VIBID_OK);
        /* A sensor gone wild (1000x the signal's spread): NIS explodes -> DIVERGED, last
         * good state kept, later steps refused until reset. */
        snap a, b;
        take(kf, &a);
        vibid_status st = VIBID_OK;
        int k = 0;
        const double wild = 40.0;
        for (k = 0; k < 50 && st == VIBID_OK; ++k) {
            take(kf, &a);
            st = vibid_kfrls_step(kf, NULL, &wild);
        }
        assert_int_equal(st, VIBID_E_DIVERGED);
        assert_true(k <= 5); /* one such sample raises the averaged NIS by ~0.02 * 1e6 */
        take(kf, &b);
        assert_memory_equal(a.x, b.x, sizeof a.x);
        assert_memory_equal(a.G, b.G, sizeof a.G);
        assert_int_equal(b.st.diverged, 1);
        assert_int_equal(vibid_kfrls_step(kf, NULL, &z[100]), VIBID_E_DIVERGED);
        assert_int_equal(vibid_kfrls_reset(kf), VIBID_OK);
        for (int j = 1; j < 100; ++j) assert_int_equal(vibid_kfrls_step(kf, NULL, &z[j]), VIBID_OK);
        vibid_kfrls_destroy(kf);

        /* A model that blows up (unstable start G, NIS check defeated by a huge prior):
         * the state_limit catches it instead of letting Inf/NaN through. */
        vibid_kfrls_config cfg;
        vibid_kfrls_config_init(&cfg, 2, 1, 0);
        cfg.first_free_row = 1;
        cfg.method = m ? VIBID_KFRLS_EKF : VIBID_KFRLS_PAPER;
        cfg.state_limit = 1e6;
        const double U[2] = {1, 0}, Rb[4] = {0, 0, 0, 1e-4}, Rv = 1e-4;
        vibid_kfrls *kf2 = vibid_kfrls_create(&cfg, U, Rb, &Rv);
        assert_non_null(kf2);
        const double G0[4] = {3.0, 0.0, 0.0, 3.0}; /* x grows 3x per step without data */
        const double S0[4] = {1, 0, 0, 1}, P[4] = {1, 0, 0, 1}, x0[2] = {1, 1};
        assert_int_equal(vibid_kfrls_start(kf2, G0, NULL, x0, S0, P), VIBID_OK);
        st = VIBID_OK;
        for (k = 0; k < 200 && st == VIBID_OK; ++k) st = vibid_kfrls_step(kf2, NULL, NULL);
        assert_int_equal(st, VIBID_E_DIVERGED);
        double x[2];
        vibid_kfrls_state(kf2, x, NULL);
        assert_true(isfinite(x[0]) && fabs(x[0]) <= 1e6 && fabs(x[1]) <= 1e6);
        vibid_kfrls_destroy(kf2);
    }
}

static void test_bad_arguments(void **state) {
    (void)state;
    vibid_kfrls_config cfg;
    vibid_kfrls_config_init(&cfg, 2, 1, 0);
    const double U[2] = {1, 0}, Rb[4] = {0, 0, 0, 1e-3}, Rv = 1e-3, Rneg = -1.0;
    const double Rasym[4] = {1, 0.5, 0, 1};
    assert_null(vibid_kfrls_create(NULL, U, Rb, &Rv));
    assert_null(vibid_kfrls_create(&cfg, NULL, Rb, &Rv));
    assert_null(vibid_kfrls_create(&cfg, U, Rb, &Rneg));
    assert_true(strstr(vibid_last_error(), "R_v") != NULL);
    assert_null(vibid_kfrls_create(&cfg, U, Rasym, &Rv));
    cfg.n_meas = 3;
    assert_null(vibid_kfrls_create(&cfg, U, Rb, &Rv));
    cfg.n_meas = 1;
    cfg.forgetting = 0.0;
    assert_null(vibid_kfrls_create(&cfg, U, Rb, &Rv));
    cfg.forgetting = 1.0;
    cfg.first_free_row = 2;
    assert_null(vibid_kfrls_create(&cfg, U, Rb, &Rv));
    cfg.first_free_row = 1;
    vibid_kfrls *kf = vibid_kfrls_create(&cfg, U, Rb, &Rv);
    assert_non_null(kf);
    const double z = 0.01;
    assert_int_equal(vibid_kfrls_step(kf, NULL, &z), VIBID_E_STATE);
    assert_int_equal(vibid_kfrls_reset(kf), VIBID_E_STATE);
    const double G0[4] = {1, -1, 0.05, 0.8}, S0[4] = {1e-3, 0, 0, 0.03}, P[4] = {0.25, 0, 0, 0.01};
    assert_int_equal(vibid_kfrls_start(kf, G0, NULL, NULL, S0, P), VIBID_OK);
    for (int k = 0; k < 20; ++k) assert_int_equal(vibid_kfrls_step(kf, NULL, &z), VIBID_OK);
    snap a, b;
    take(kf, &a);
    const double Pnpd[4] = {1, 2, 2, 1}, Sasym[4] = {1, 0.3, 0, 1}, Gnan[4] = {1, NAN, 0.05, 0.8};
    assert_int_equal(vibid_kfrls_start(kf, G0, NULL, NULL, S0, Pnpd), VIBID_E_NUMERICAL);
    assert_int_equal(vibid_kfrls_start(kf, G0, NULL, NULL, Sasym, P), VIBID_E_OUT_OF_RANGE);
    assert_int_equal(vibid_kfrls_start(kf, Gnan, NULL, NULL, S0, P), VIBID_E_NONFINITE);
    assert_int_equal(vibid_kfrls_start(kf, NULL, NULL, NULL, S0, P), VIBID_E_NULL_ARGUMENT);
    assert_int_equal(vibid_kfrls_step(NULL, NULL, &z), VIBID_E_NULL_ARGUMENT);
    take(kf, &b);
    assert_same(&a, &b);
    vibid_kfrls_destroy(kf);
    vibid_kfrls_destroy(NULL);
}

/* Known input: x_{k+1} = x_k + h r_k, r_{k+1} = c x_k + d r_k + b u_k + 0.1 h w_k with u
 * measured. The EKF estimates [c d b] (free row 1 of [G H]); after 20000 steps the
 * estimates are within 2 % (measured: 0.01 %; a bug such as a misplaced H column gives
 * errors of order 100 %). The PAPER method cannot learn b here (see below). */
static void test_known_input(void **state) {
    (void)state;
    const double h = 0.05, c = -1.25, d = 0.9, b = 0.5;
    enum { N = 20000 };
    double *z = malloc(sizeof(double) * N), *u = malloc(sizeof(double) * N);
    assert_non_null(z);
    assert_non_null(u);
    ex3_rng g;
    ex3_rng_seed(&g, 11);
    double x = 0, r = 0;
    for (int k = 0; k < N; ++k) {
        u[k] = ex3_rng_normal(&g);
        z[k] = x + 1e-3 * ex3_rng_normal(&g);
        const double xn = x + h * r, rn = c * x + d * r + b * u[k] + 0.1 * h * ex3_rng_normal(&g);
        x = xn;
        r = rn;
    }
    for (int m = 0; m < 2; ++m) {
        vibid_kfrls_config cfg;
        vibid_kfrls_config_init(&cfg, 2, 1, 1);
        cfg.first_free_row = 1;
        cfg.method = m ? VIBID_KFRLS_EKF : VIBID_KFRLS_PAPER;
        const double U[2] = {1, 0}, Rb[4] = {0, 0, 0, 0.01 * h * h}, Rv = 1e-6;
        vibid_kfrls *kf = vibid_kfrls_create(&cfg, U, Rb, &Rv);
        assert_non_null(kf);
        const double G0[4] = {1, -1.0, h, 0.8}, H0[2] = {0, 0.3}, S0[4] = {1e-6, 0, 0, 1};
        const double P[9] = {1, 0, 0, 0, 0.1, 0, 0, 0, 1};
        assert_int_equal(vibid_kfrls_start(kf, G0, H0, NULL, S0, P), VIBID_OK);
        assert_int_equal(vibid_kfrls_step(kf, NULL, &z[1]), VIBID_E_NULL_ARGUMENT);
        const double unan = NAN;
        assert_int_equal(vibid_kfrls_step(kf, &unan, &z[1]), VIBID_E_NONFINITE);
        if (m == 0) {
            /* PAPER: the effect of u_k on r_{k+1} reaches z only at k+2, after the one RLS
             * step that could learn it, so the regression confirms its own b (measured:
             * b -> -0.04 with the NIS check off). With this poor start the filter is
             * grossly inconsistent and the NIS check must report it instead of returning
             * that garbage. */
            vibid_status st = VIBID_OK;
            int k = 0;
            for (k = 0; k + 1 < N && st == VIBID_OK; ++k) st = vibid_kfrls_step(kf, &u[k], &z[k + 1]);
            assert_int_equal(st, VIBID_E_DIVERGED);
            assert_true(k < 100);
            vibid_kfrls_destroy(kf);
            continue;
        }
        for (int k = 0; k + 1 < N; ++k) assert_int_equal(vibid_kfrls_step(kf, &u[k], &z[k + 1]), VIBID_OK);
        double G[4], H[2];
        vibid_kfrls_model(kf, G, H);
        assert_true(fabs(G[1] / c - 1) < 0.02);
        assert_true(fabs(G[3] / d - 1) < 0.02);
        assert_true(fabs(H[1] / b - 1) < 0.02);
        assert_true(G[0] == 1.0 && G[2] == h && H[0] == 0.0); /* known row untouched */
        vibid_kfrls_destroy(kf);
    }
    free(z);
    free(u);
}

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_ioform_known_answer), cmocka_unit_test(test_ioform_recursive),
        cmocka_unit_test(test_ioform_modes),
        cmocka_unit_test(test_ioform_recover_g),    cmocka_unit_test(test_long_run_spd),
        cmocka_unit_test(test_nan_and_missing),     cmocka_unit_test(test_divergence),
        cmocka_unit_test(test_bad_arguments),       cmocka_unit_test(test_known_input),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
