/* bench_ident.c: cost of one sample through vibid_ident_push (regressor, pre-filter and
 * estimator), ns per sample, for the automatic estimator (the default: IV with block
 * statistics, five-point stencils, automatic pre-filter) against the RLS path that was the
 * daemon's default before it (central differences, 200 Hz pre-filter, Bierman RLS), in
 * the same run, on two stands: the paper's example 1 (2 DOF, 3 unknowns, 3 channels) and a
 * 3-DOF chain (6 unknowns, 7 channels). Also the cost of one estimate (vibid_ident_estimate,
 * at the track-row rate, not per sample), of the one push that ends the pre-filter
 * pilot on a stand without nominal values, and of the output-error fit (output_error.h) of
 * the 3-DOF chain on 10^5 samples beside the automatic estimator's identification of the
 * same samples (its start values).
 *
 * Usage: bench_ident [scale]  (scale multiplies the samples timed, default 1)
 * Each figure is the best of 3 repetitions. Prints a table; never fails on time. */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include <unistd.h>

#include <vibid/identify.h>
#include <vibid/output_error.h>
#include <vibid/model.h>
#include <vibid/stand_file.h>

#include "sim_config.h"
#include "sim_engine.h"

#include "bench_stands.h"
#include "chain_stand.h" /* tests/ident: the stand of ident.default */

#define H (1.0 / 2000.0)

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void die(const char *what)
{
    fprintf(stderr, "bench_ident: %s\n", what);
    exit(1);
}

/* Loads chain_stand (tests/ident/chain_stand.h; *stand, the caller destroys it) and
 * simulates n samples of its channels, sample-major (malloc'd, the caller frees). */
static double *pilot_capture(long n, vibid_stand **stand, size_t *nc)
{
    char path[] = "/tmp/bench_ident_XXXXXX", err[1024];
    const int fd = mkstemp(path);
    if (fd < 0) die("cannot create a temporary stand file");
    FILE *f = fdopen(fd, "w");
    if (!f || fputs(chain_stand, f) < 0 || fclose(f)) die("cannot write the temporary stand file");
    vibid_stand_error serr;
    *stand = vibid_stand_load(path, &serr);
    if (!*stand) die(serr.text);
    sim_config cfg;
    if (sim_config_load(path, *stand, NULL, &cfg, err, sizeof err)) die(err);
    unlink(path);
    sim_engine *e = sim_engine_create(*stand, &cfg, err, sizeof err);
    if (!e) die(err);
    *nc = sim_engine_channels(e);
    double *data = malloc((size_t)n * *nc * sizeof(double));
    if (!data) die("out of memory");
    for (long k = 0; k < n; k++) {
        uint64_t kk;
        double t;
        if (sim_engine_next(e, &kk, &t, data + (size_t)k * *nc, NULL)) die(sim_engine_error(e));
    }
    sim_engine_destroy(e);
    sim_config_free(&cfg);
    return data;
}

/* The push that ends the pre-filter pilot (chain without nominal values, the automatic
 * estimator): its time, beside the yardstick of pushing the pilot's samples once through
 * the former default RLS. Best of 3. */
static void time_pilot_end(void)
{
    enum { PILOT = 4096 };
    vibid_stand *stand;
    size_t nc;
    double *data = pilot_capture(PILOT, &stand, &nc);
    const vibid_model *m = vibid_stand_model(stand);
    vibid_ident_config aut, rls, used;
    vibid_ident_config_init(&aut, H);
    vibid_ident_config_init(&rls, H);
    rls.estimator = VIBID_ESTIMATOR_RLS;
    rls.prefilter_hz = 200.0;
    rls.difference_order = 2;
    double best_end = 1e300, best_rls = 1e300;
    for (int rep = 0; rep < 3; rep++) {
        vibid_ident *id = vibid_ident_create(m, &aut), *yard = vibid_ident_create(m, &rls);
        if (!id || !yard) die(vibid_last_error());
        for (long k = 0; k < PILOT - 1; k++) vibid_ident_push(id, data + (size_t)k * nc);
        double t0 = now_s();
        vibid_ident_push(id, data + (size_t)(PILOT - 1) * nc);
        best_end = fmin(best_end, now_s() - t0);
        t0 = now_s();
        for (long k = 0; k < PILOT; k++) vibid_ident_push(yard, data + (size_t)k * nc);
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
    vibid_stand_destroy(stand);
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

/* The output-error fit of the chain (tests/ident/chain_stand.h: 6 unknowns, x and a on each
 * of 3 nodes, a held force) on n samples with 0.5 % white noise on the response channels:
 * its time (one core, wall clock), iterations and errors, beside the automatic estimator's
 * identification of the same samples (push and estimate: the fit's start values). */
static void time_output_error(long n)
{
    vibid_stand *stand;
    size_t nc;
    double *rows = pilot_capture(n, &stand, &nc);
    const vibid_model *m = vibid_stand_model(stand);
    const double *truth = vibid_stand_true_values(stand);
    double *cols = malloc((size_t)n * nc * sizeof(double));
    if (!cols) die("out of memory");
    uint64_t st = 0x9E3779B97F4A7C15ull;
    for (size_t j = 0; j < nc; j++) {
        vibid_channel_info ci;
        vibid_model_channel_info(m, j, &ci);
        double rms = 0.0;
        for (long k = 0; k < n; k++) rms += rows[(size_t)k * nc + j] * rows[(size_t)k * nc + j];
        rms = sqrt(rms / (double)n);
        for (long k = 0; k < n; k++) {
            double g = 0.0; /* Irwin-Hall(12) - 6: a unit-variance, nearly Gaussian value */
            for (int i = 0; i < 12; i++) {
                st ^= st << 13; st ^= st >> 7; st ^= st << 17;
                g += (double)(st >> 11) / 9007199254740992.0;
            }
            cols[(size_t)k + j * (size_t)n] = rows[(size_t)k * nc + j] + (ci.kind == VIBID_CHANNEL_INPUT ? 0.0 : 0.005 * rms * (g - 6.0));
        }
    }
    vibid_ident_config ic;
    vibid_ident_config_init(&ic, H);
    double t0 = now_s();
    vibid_ident *id = vibid_ident_create(m, &ic);
    if (!id || vibid_ident_push_block(id, (size_t)n, cols) != VIBID_OK) die(vibid_last_error());
    double th0[8], se0[8], th[8], se[8];
    if (vibid_ident_estimate(id, th0, se0, NULL) != VIBID_OK) die(vibid_last_error());
    const double t_auto = now_s() - t0;
    vibid_oe_config oc;
    vibid_oe_config_init(&oc, H);
    vibid_oe *oe = vibid_oe_create(m, &oc);
    if (!oe) die(vibid_last_error());
    t0 = now_s();
    if (vibid_oe_fit(oe, (size_t)n, cols, 1, th0) != VIBID_OK) die(vibid_last_error());
    const double t_oe = now_s() - t0;
    vibid_oe_fit_info info;
    vibid_oe_result(oe, th, se, NULL, NULL, NULL, NULL, &info);
    double worst_auto = 0.0, worst_oe = 0.0, zmax = 0.0;
    for (int i = 0; i < 6; i++) {
        worst_auto = fmax(worst_auto, fabs(th0[i] / truth[i] - 1.0));
        worst_oe = fmax(worst_oe, fabs(th[i] / truth[i] - 1.0));
        zmax = fmax(zmax, fabs(th[i] - truth[i]) / se[i]);
    }
    printf("\noutput-error fit, chain 3 DOF (p = 6, 6 response channels), %ld samples, 0.5 %% noise, one core:\n", n);
    printf("  automatic estimator (push + estimate, the start): %8.3f s, largest error %.4f %%\n", t_auto,
           100.0 * worst_auto);
    printf("  output-error fit from it:                        %8.3f s (%.2f x the automatic), %u iterations, "
           "largest error %.4f %%, largest |z| %.2f\n",
           t_oe, t_oe / t_auto, info.iterations, 100.0 * worst_oe, zmax);
    vibid_oe_destroy(oe);
    vibid_ident_destroy(id);
    free(cols);
    free(rows);
    vibid_stand_destroy(stand);
}

int main(int argc, char **argv)
{
    double scale = argc > 1 ? atof(argv[1]) : 1.0;
    long n = (long)(200000 * (scale > 0 ? scale : 1.0));
    struct {
        const char *name;
        vibid_model *m;
    } stands[2] = {{"example 1 (p = 3)", bench_example1()}, {"chain 3 DOF (p = 6)", bench_chain3()}};
    printf("%-22s %-44s %12s %12s %9s\n", "stand", "estimator", "ns/sample", "estimate us", "ratio");
    for (int s = 0; s < 2; s++) {
        vibid_ident_config rls, aut, aut_f, aut_off;
        vibid_ident_config_init(&rls, H);
        rls.estimator = VIBID_ESTIMATOR_RLS; /* the former daemon default */
        rls.prefilter_hz = 200.0;
        rls.difference_order = 2;
        vibid_ident_config_init(&aut, H); /* the automatic estimator, all defaults */
        vibid_ident_config_init(&aut_f, H);
        aut_f.forgetting = 0.999;
        vibid_ident_config_init(&aut_off, H); /* without the constant-force columns */
        aut_off.constant_terms = VIBID_CONSTANT_OFF;
        double e0, e1, e2, e3;
        double t_rls = time_push(stands[s].m, &rls, n, &e0);
        double t_auto = time_push(stands[s].m, &aut, n, &e1);
        double t_auto_f = time_push(stands[s].m, &aut_f, n, &e2);
        double t_auto_off = time_push(stands[s].m, &aut_off, n, &e3);
        printf("%-22s %-44s %12.1f %12.1f %9s\n", stands[s].name, "RLS, (1.17), 200 Hz pre-filter (yardstick)", t_rls,
               e0, "1.00");
        printf("%-22s %-44s %12.1f %12.1f %9.2f\n", stands[s].name, "auto (IV, block statistics)", t_auto, e1,
               t_auto / t_rls);
        printf("%-22s %-44s %12.1f %12.1f %9.2f\n", stands[s].name, "auto with forgetting 0.999", t_auto_f, e2,
               t_auto_f / t_rls);
        printf("%-22s %-44s %12.1f %12.1f %9.2f\n", stands[s].name, "auto, constant terms off", t_auto_off, e3,
               t_auto_off / t_rls);
        vibid_model_destroy(stands[s].m);
    }
    time_pilot_end();
    time_output_error(100000);
    return 0;
}
