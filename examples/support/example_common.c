/* example_common.c: see example_common.h. */
#include "example_common.h"

#include <math.h>
#include <stdlib.h>

static int ok(vibid_status s, const char *what) {
    if (s != VIBID_OK) {
        fprintf(stderr, "%s: %s (%s)\n", what, vibid_strerror(s), vibid_last_error());
        return 0;
    }
    return 1;
}

vibid_model *example_two_mass_model(double m1, double m2, double c1, double d, double c2, double cubic_eps,
                                    vibid_discretization disc) {
    vibid_model *m = vibid_model_create();
    size_t n1 = 0, n2 = 0;
    if (!m) return NULL;
    int good = ok(vibid_model_add_node(m, "m1", m1, 0, &n1), "node m1") &&
               ok(vibid_model_add_node(m, "m2", m2, 0, &n2), "node m2") &&
               ok(vibid_model_add_element(m, "c1", VIBID_ELEMENT_SPRING, n1, n2, c1, 1), "c1") &&
               ok(vibid_model_add_element(m, "d", VIBID_ELEMENT_DAMPER, n1, n2, d, 1), "d") &&
               ok(vibid_model_add_element(m, "c2", VIBID_ELEMENT_SPRING, n2, VIBID_BASE, c2, 1), "c2");
    if (good && cubic_eps != 0.0)
        good = ok(vibid_model_add_element(m, "eps", VIBID_ELEMENT_CUBIC_SPRING, n2, VIBID_BASE, cubic_eps, 1), "eps");
    good = good && ok(vibid_model_set_measured(m, n1, VIBID_MEASURE_DISPLACEMENT), "measure m1") &&
           ok(vibid_model_set_measured(m, n2, VIBID_MEASURE_DISPLACEMENT), "measure m2") &&
           ok(vibid_model_set_measured(m, VIBID_BASE, VIBID_MEASURE_DISPLACEMENT), "measure base") &&
           ok(vibid_model_set_discretization(m, disc), "discretization") && ok(vibid_model_finalize(m), "finalize");
    if (!good) {
        vibid_model_destroy(m);
        return NULL;
    }
    return m;
}

int example_run_case(const example_case *c, const vibid_model *model, double h, const double *record,
                     size_t n_samples, const size_t *checkpoints, size_t n_checkpoints, const double *truth, FILE *csv,
                     double *rel_err_out) {
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, h);
    cfg.estimator = c->estimator;
    cfg.prefilter_hz = c->prefilter_hz;
    if (c->iv_lag) cfg.iv_lag = c->iv_lag;
    vibid_model *local = vibid_model_clone(model);
    if (!local) return -1;
    /* The case picks the discretization: rebuild the frozen model with it. */
    vibid_model_dims dims;
    vibid_model_get_dims(model, &dims);
    vibid_ident *id = NULL;
    if (dims.discretization != c->disc) {
        vibid_model_destroy(local);
        double eps = 0.0, th[4] = {0};
        vibid_model_nominal(model, th);
        if (dims.n_params == 4) eps = th[3];
        /* masses from the assembled M */
        double M[4];
        vibid_model_assemble(model, NULL, M, NULL, NULL, NULL, NULL, NULL);
        local = example_two_mass_model(M[0], M[3], th[0], th[1], th[2], eps, c->disc);
        if (!local) return -1;
    }
    id = vibid_ident_create(local, &cfg);
    if (!id) {
        fprintf(stderr, "case %s: %s\n", c->name, vibid_last_error());
        vibid_model_destroy(local);
        return -1;
    }
    size_t nc = 0, p = 0;
    vibid_ident_dims(id, &nc, &p);
    double sample[16], theta[8], se[8];
    size_t next = 0;
    int rc = 0;
    printf("  %-22s %7s", c->name, "N");
    for (size_t i = 0; i < p; ++i) {
        vibid_param_info pi;
        vibid_model_param_info(local, i, &pi);
        printf(" %14s %9s", pi.name, "err%");
    }
    printf("\n");
    for (size_t k = 0; k < n_samples && next < n_checkpoints; ++k) {
        for (size_t ch = 0; ch < nc; ++ch) sample[ch] = record[k + ch * n_samples];
        if (!ok(vibid_ident_push(id, sample), "push")) {
            rc = -1;
            break;
        }
        if (k + 1 == checkpoints[next]) {
            vibid_status s = vibid_ident_estimate(id, theta, se, NULL);
            printf("  %-22s %7zu", c->name, checkpoints[next]);
            if (s == VIBID_OK) {
                for (size_t i = 0; i < p; ++i)
                    printf(" %14.6g %+9.3f", theta[i], 100.0 * (theta[i] - truth[i]) / truth[i]);
                if (csv) {
                    fprintf(csv, "%s,%zu", c->name, checkpoints[next]);
                    for (size_t i = 0; i < p; ++i) fprintf(csv, ",%.10g,%.6g", theta[i], se[i]);
                    fprintf(csv, "\n");
                }
                if (rel_err_out && next + 1 == n_checkpoints)
                    for (size_t i = 0; i < p; ++i) rel_err_out[i] = fabs(theta[i] - truth[i]) / fabs(truth[i]);
            } else {
                printf("  (%s: %s)", vibid_strerror(s), vibid_last_error());
            }
            printf("\n");
            ++next;
        }
    }
    vibid_ident_destroy(id);
    vibid_model_destroy(local);
    return rc;
}
