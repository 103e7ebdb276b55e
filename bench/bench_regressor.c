/* bench_regressor.c: cost of one vibid_regressor_push (the regressor and the pre-filter of
 * the central-difference structured form), ns per sample, on the paper's example 1 (2 DOF,
 * 3 channels, p = 3, m = 2), a 3-DOF chain with accelerometers and a held force (7
 * channels, p = 6, m = 3) and a 10-DOF chain (11 channels, p = 20, m = 10), difference
 * order 2 and 4, with and without the 200 Hz pre-filter. Yardstick: vibid_rls_update
 * (Bierman, the daemon's RLS) on the rows the regressor made, in the same run: the
 * estimator step the regressor feeds.
 *
 * Usage: bench_regressor [scale]  (scale multiplies the samples timed, default 1)
 * Each figure is the best of 5 repetitions, in thread CPU time. Prints a table; never fails
 * on time. */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include <vibid/regressor.h>
#include <vibid/rls.h>

#include "bench_stands.h"

#define H (1.0 / 2000.0)
#define K 4096 /* distinct samples, cycled */

/* CPU time of this thread: time while other processes hold the core is not counted (the
 * machine may be shared), only what they leave behind in the caches. */
static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void die(const char *what)
{
    fprintf(stderr, "bench_regressor: %s: %s\n", what, vibid_last_error());
    exit(1);
}

/* Ten masses in a row from the moving base, every spring and damper unknown, displacements
 * measured (p = 20, m = 10, 11 channels): a model whose entries read few of the window's
 * values each. */
static vibid_model *chain10(void)
{
    vibid_model *m = vibid_model_create();
    size_t prev = VIBID_BASE, node = 0;
    for (int i = 0; i < 10; i++) {
        char name[16];
        snprintf(name, sizeof name, "m%d", i);
        vibid_model_add_node(m, name, 1.0 + 0.1 * i, 0, &node);
        snprintf(name, sizeof name, "k%d", i);
        vibid_model_add_element(m, name, VIBID_ELEMENT_SPRING, node, prev, 1e4 * (1 + i), 1);
        snprintf(name, sizeof name, "d%d", i);
        vibid_model_add_element(m, name, VIBID_ELEMENT_DAMPER, node, prev, 5.0 + i, 1);
        vibid_model_set_measured(m, node, VIBID_MEASURE_DISPLACEMENT);
        prev = node;
    }
    vibid_model_set_measured(m, VIBID_BASE, VIBID_MEASURE_DISPLACEMENT);
    if (vibid_model_finalize(m) != VIBID_OK) die("chain10");
    return m;
}

/* ns per push and per RLS update of the pushed rows (best of 5 each) for one configuration. */
static void time_one(const vibid_model *m, unsigned order, double fc, long n, double *t_reg, double *t_rls)
{
    vibid_model_dims md;
    vibid_model_get_dims(m, &md);
    vibid_regressor *reg = vibid_regressor_create_order(m, H, fc, order);
    if (!reg) die("regressor");
    vibid_regressor_dims d;
    vibid_regressor_get_dims(reg, &d);
    const size_t nc = md.n_channels, nx = d.n_regressors * d.n_equations, ny = d.n_equations * d.n_outputs;
    double *data = malloc(K * nc * sizeof(double));
    double *rows = malloc((size_t)K * (nx + ny) * sizeof(double));
    if (!data || !rows) die("out of memory");
    for (int k = 0; k < K; k++)
        for (size_t c = 0; c < nc; c++)
            data[(size_t)k * nc + c] = 1e-3 * sin(0.0123 * k * (double)(c + 1)) + 1e-4 * cos(0.731 * k + (double)c);
    vibid_rls_config cfg;
    vibid_rls_config_init(&cfg, d.n_regressors, d.n_outputs);
    cfg.n_equations = d.n_equations;
    vibid_rls *rls = vibid_rls_create(&cfg);
    if (!rls) die("rls");
    *t_reg = *t_rls = 1e300;
    for (int rep = 0; rep < 5; rep++) {
        int ready;
        vibid_regressor_reset(reg);
        double t0 = now_s();
        for (long k = 0; k < n; k++) {
            const long j = k % K;
            vibid_regressor_push(reg, data + (size_t)j * nc, rows + (size_t)j * (nx + ny),
                                 rows + (size_t)j * (nx + ny) + nx, &ready);
        }
        *t_reg = fmin(*t_reg, (now_s() - t0) / (double)n);
        vibid_rls_reset(rls);
        t0 = now_s();
        for (long k = 0; k < n; k++) {
            const long j = (k % (K - 8)) + 8; /* rows of the first pushes may be unset */
            vibid_rls_update(rls, rows + (size_t)j * (nx + ny), rows + (size_t)j * (nx + ny) + nx);
        }
        *t_rls = fmin(*t_rls, (now_s() - t0) / (double)n);
    }
    *t_reg *= 1e9;
    *t_rls *= 1e9;
    vibid_rls_destroy(rls);
    vibid_regressor_destroy(reg);
    free(rows);
    free(data);
}

int main(int argc, char **argv)
{
    const double scale = argc > 1 ? atof(argv[1]) : 1.0;
    const long n = (long)(400000 * (scale > 0 ? scale : 1.0));
    struct {
        const char *name;
        vibid_model *m;
    } stands[3] = {{"example 1 (p = 3, m = 2)", bench_example1()},
                   {"chain 3 DOF (p = 6, m = 3)", bench_chain3()},
                   {"chain 10 DOF (p = 20, m = 10)", chain10()}};
    printf("%-30s %-26s %14s %20s %7s\n", "stand", "regressor", "push ns/sample", "yardstick: RLS ns", "ratio");
    for (int s = 0; s < 3; s++) {
        for (unsigned order = 2; order <= 4; order += 2)
            for (int f = 0; f < 2; f++) {
                const double fc = f ? 200.0 : 0.0;
                double t_reg, t_rls;
                char what[64];
                time_one(stands[s].m, order, fc, n, &t_reg, &t_rls);
                snprintf(what, sizeof what, "order %u, %s", order, f ? "200 Hz pre-filter" : "no pre-filter");
                printf("%-30s %-26s %14.1f %20.1f %7.2f\n", stands[s].name, what, t_reg, t_rls, t_reg / t_rls);
            }
        vibid_model_destroy(stands[s].m);
    }
    return 0;
}
