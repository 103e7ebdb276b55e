/* bench_ident.c: cost of one sample through vibid_ident_push (regressor, pre-filter and
 * estimator), ns per sample, for the automatic estimator (the default: IV with block
 * statistics, five-point stencils, automatic pre-filter) against the RLS path that was the
 * daemon's default before it (central differences, 200 Hz pre-filter, Bierman RLS), in
 * the same run, on two stands: the paper's example 1 (2 DOF, 3 unknowns, 3 channels) and a
 * 3-DOF chain (6 unknowns, 7 channels). Also the cost of one estimate (vibid_ident_estimate,
 * at the track-row rate, not per sample), and of the one push that ends the pre-filter
 * pilot on a stand without nominal values.
 *
 * Usage: bench_ident [scale]  (scale multiplies the samples timed, default 1)
 * Each figure is the best of 3 repetitions. Prints a table; never fails on time. */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include <vibid/identify.h>
#include <vibid/model.h>

#define H (1.0 / 2000.0)

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static vibid_model *example1(void)
{
    vibid_model *m = vibid_model_create();
    size_t a, b;
    vibid_model_add_node(m, "m1", 10.0, 0, &a);
    vibid_model_add_node(m, "m2", 20.0, 0, &b);
    vibid_model_add_element(m, "c1", VIBID_ELEMENT_SPRING, a, b, 2.5e5, 1);
    vibid_model_add_element(m, "d", VIBID_ELEMENT_DAMPER, a, b, 300.0, 1);
    vibid_model_add_element(m, "c2", VIBID_ELEMENT_SPRING, b, VIBID_BASE, 1.5e6, 1);
    vibid_model_set_measured(m, a, VIBID_MEASURE_DISPLACEMENT);
    vibid_model_set_measured(m, b, VIBID_MEASURE_DISPLACEMENT);
    vibid_model_set_measured(m, VIBID_BASE, VIBID_MEASURE_DISPLACEMENT);
    vibid_model_finalize(m);
    return m;
}

/* The chain; nominal = 0 gives it no nominal values (so the automatic estimator runs the
 * pre-filter pilot). */
static vibid_model *chain3_nominal(int nominal)
{
    vibid_model *m = vibid_model_create();
    size_t n[3];
    const char *names[3] = {"m1", "m2", "m3"};
    for (int i = 0; i < 3; i++) {
        vibid_model_add_node(m, names[i], 1.0 + 0.5 * i, 0, &n[i]);
        vibid_model_set_measured(m, n[i], VIBID_MEASURE_DISPLACEMENT | VIBID_MEASURE_ACCELERATION);
    }
    const double v = nominal ? 1.0 : 0.0;
    vibid_model_add_element(m, "k1", VIBID_ELEMENT_SPRING, n[0], VIBID_GROUND, 4e4 * v, 1);
    vibid_model_add_element(m, "d1", VIBID_ELEMENT_DAMPER, n[0], VIBID_GROUND, 20 * v, 1);
    vibid_model_add_element(m, "k2", VIBID_ELEMENT_SPRING, n[1], n[0], 3e4 * v, 1);
    vibid_model_add_element(m, "d2", VIBID_ELEMENT_DAMPER, n[1], n[0], 15 * v, 1);
    vibid_model_add_element(m, "k3", VIBID_ELEMENT_SPRING, n[2], n[1], 2e4 * v, 1);
    vibid_model_add_element(m, "d3", VIBID_ELEMENT_DAMPER, n[2], n[1], 10 * v, 1);
    size_t in;
    vibid_model_add_input(m, "f", n[2], 1.0, 0, &in);
    vibid_model_set_hold(m, in, VIBID_HOLD_ZOH);
    vibid_model_finalize(m);
    return m;
}

static vibid_model *chain3(void) { return chain3_nominal(1); }

/* The chain's response to a held random force (uniform, +-50 N, new each sample), by RK4
 * with 10 steps per sample: n samples of the channels x1 a1 x2 a2 x3 a3 f, sample-major
 * (malloc'd, the caller frees). Accurate enough for a timing run, which needs only an
 * estimate with modes where the stand has them. */
static double *chain3_response(long n)
{
    const double mass[3] = {1.0, 1.5, 2.0}, k[3] = {4e4, 3e4, 2e4}, d[3] = {20, 15, 10};
    double x[3] = {0}, v[3] = {0}, *out = malloc((size_t)n * 7 * sizeof(double));
    unsigned seed = 12345u;
    for (long s = 0; s < n; s++) {
        seed = seed * 1103515245u + 12345u;
        const double f = 100.0 * ((double)(seed >> 8) / 16777216.0 - 0.5);
        double acc[3];
        for (int sub = 0; sub <= 10; sub++) {
            /* accelerations of state (xs, vs): springs/dampers k1 d1 to ground, k2 d2 and
             * k3 d3 between neighbours, the force on node 3 */
            double kx[4][3], kv[4][3], xs[3], vs[3];
            for (int st = 0; st < 4; st++) {
                const double c = st == 0 ? 0.0 : (st == 3 ? 1.0 : 0.5);
                for (int i = 0; i < 3; i++) {
                    xs[i] = x[i] + (st ? c * (H / 10) * kx[st - 1][i] : 0.0);
                    vs[i] = v[i] + (st ? c * (H / 10) * kv[st - 1][i] : 0.0);
                }
                const double f1 = k[0] * xs[0] + d[0] * vs[0], f2 = k[1] * (xs[1] - xs[0]) + d[1] * (vs[1] - vs[0]),
                             f3 = k[2] * (xs[2] - xs[1]) + d[2] * (vs[2] - vs[1]);
                const double a[3] = {(-f1 + f2) / mass[0], (-f2 + f3) / mass[1], (-f3 + f) / mass[2]};
                for (int i = 0; i < 3; i++) {
                    kx[st][i] = vs[i];
                    kv[st][i] = a[i];
                }
                if (st == 0)
                    for (int i = 0; i < 3; i++) acc[i] = a[i];
            }
            if (sub == 0) {
                for (int i = 0; i < 3; i++) {
                    out[(size_t)s * 7 + 2 * (size_t)i] = x[i];
                    out[(size_t)s * 7 + 2 * (size_t)i + 1] = acc[i];
                }
                out[(size_t)s * 7 + 6] = f;
            }
            if (sub == 10) break;
            for (int i = 0; i < 3; i++) {
                x[i] += (H / 10) / 6.0 * (kx[0][i] + 2 * kx[1][i] + 2 * kx[2][i] + kx[3][i]);
                v[i] += (H / 10) / 6.0 * (kv[0][i] + 2 * kv[1][i] + 2 * kv[2][i] + kv[3][i]);
            }
        }
    }
    return out;
}

/* The push that ends the pre-filter pilot (chain without nominal values, the automatic
 * estimator): its time, beside the yardstick of pushing the pilot's samples once through
 * the former default RLS. Best of 3. */
static void time_pilot_end(void)
{
    enum { PILOT = 4096 };
    vibid_model *m = chain3_nominal(0);
    double *data = chain3_response(PILOT);
    vibid_ident_config aut, rls, used;
    vibid_ident_config_init(&aut, H);
    vibid_ident_config_init(&rls, H);
    rls.estimator = VIBID_ESTIMATOR_RLS;
    rls.prefilter_hz = 200.0;
    rls.difference_order = 2;
    double best_end = 1e300, best_rls = 1e300;
    for (int rep = 0; rep < 3; rep++) {
        vibid_ident *id = vibid_ident_create(m, &aut), *yard = vibid_ident_create(m, &rls);
        if (!id || !yard) {
            fprintf(stderr, "bench_ident: %s\n", vibid_last_error());
            exit(1);
        }
        for (long k = 0; k < PILOT - 1; k++) vibid_ident_push(id, data + (size_t)k * 7);
        double t0 = now_s();
        vibid_ident_push(id, data + (size_t)(PILOT - 1) * 7);
        best_end = fmin(best_end, now_s() - t0);
        t0 = now_s();
        for (long k = 0; k < PILOT; k++) vibid_ident_push(yard, data + (size_t)k * 7);
        best_rls = fmin(best_rls, now_s() - t0);
        vibid_ident_get_config(id, &used);
        vibid_ident_destroy(id);
        vibid_ident_destroy(yard);
    }
    printf("\npre-filter pilot, chain 3 DOF without nominal values (%d samples, chose %.4g Hz):\n", PILOT,
           used.prefilter_hz);
    printf("  %-62s %10.2f ms\n", "the push that ends the pilot (estimates, candidate replays)", 1e3 * best_end);
    printf("  %-62s %10.2f ms  ratio %.1f\n", "yardstick: the pilot's samples through RLS, (1.17), 200 Hz", 1e3 * best_rls,
           best_end / best_rls);
    free(data);
    vibid_model_destroy(m);
}

/* ns per sample of vibid_ident_push, best of 3; *est_us: one vibid_ident_estimate. */
static double time_push(const vibid_model *m, const vibid_ident_config *cfg, long n, double *est_us)
{
    size_t nc, p;
    vibid_ident *id = vibid_ident_create(m, cfg);
    if (!id) {
        fprintf(stderr, "bench_ident: %s\n", vibid_last_error());
        exit(1);
    }
    vibid_ident_dims(id, &nc, &p);
    enum { K = 4096 };
    double *data = malloc(K * nc * sizeof(double)), theta[16], se[16];
    for (int k = 0; k < K; k++)
        for (size_t c = 0; c < nc; c++)
            data[(size_t)k * nc + c] = 1e-3 * sin(0.0123 * k * (double)(c + 1)) + 1e-4 * cos(0.731 * k + (double)c);
    double best = 1e300, best_est = 1e300;
    for (int rep = 0; rep < 3; rep++) {
        vibid_ident_reset(id);
        double t0 = now_s();
        for (long k = 0; k < n; k++) vibid_ident_push(id, data + (size_t)(k % K) * nc);
        double dt = (now_s() - t0) / (double)n;
        if (dt < best) best = dt;
        t0 = now_s();
        vibid_ident_estimate(id, theta, se, NULL);
        dt = now_s() - t0;
        if (dt < best_est) best_est = dt;
    }
    free(data);
    vibid_ident_destroy(id);
    *est_us = 1e6 * best_est;
    return 1e9 * best;
}

int main(int argc, char **argv)
{
    double scale = argc > 1 ? atof(argv[1]) : 1.0;
    long n = (long)(200000 * (scale > 0 ? scale : 1.0));
    struct {
        const char *name;
        vibid_model *m;
    } stands[2] = {{"example 1 (p = 3)", example1()}, {"chain 3 DOF (p = 6)", chain3()}};
    printf("%-22s %-44s %12s %12s %9s\n", "stand", "estimator", "ns/sample", "estimate us", "ratio");
    for (int s = 0; s < 2; s++) {
        vibid_ident_config rls, aut, aut_f;
        vibid_ident_config_init(&rls, H);
        rls.estimator = VIBID_ESTIMATOR_RLS; /* the former daemon default */
        rls.prefilter_hz = 200.0;
        rls.difference_order = 2;
        vibid_ident_config_init(&aut, H); /* the automatic estimator, all defaults */
        vibid_ident_config_init(&aut_f, H);
        aut_f.forgetting = 0.999;
        double e0, e1, e2;
        double t_rls = time_push(stands[s].m, &rls, n, &e0);
        double t_auto = time_push(stands[s].m, &aut, n, &e1);
        double t_auto_f = time_push(stands[s].m, &aut_f, n, &e2);
        printf("%-22s %-44s %12.1f %12.1f %9s\n", stands[s].name, "RLS, (1.17), 200 Hz pre-filter (yardstick)", t_rls,
               e0, "1.00");
        printf("%-22s %-44s %12.1f %12.1f %9.2f\n", stands[s].name, "auto (IV, block statistics)", t_auto, e1,
               t_auto / t_rls);
        printf("%-22s %-44s %12.1f %12.1f %9.2f\n", stands[s].name, "auto with forgetting 0.999", t_auto_f, e2,
               t_auto_f / t_rls);
        vibid_model_destroy(stands[s].m);
    }
    time_pilot_end();
    return 0;
}
