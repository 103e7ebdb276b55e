/* test_report.c: vibid_report_row (vibid/report.h), the one row of vibidd and the Python
 * package: an estimate that breaks a rule and is unstable keeps both reasons (the
 * unstable message appended after the rules' findings; vibidd used to drop it), a row
 * without estimate says why, bad arguments are refused, and an estimate made elsewhere
 * (vibid_report_estimate) gets the same checks. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>

#include <math.h>
#include <string.h>

#include <vibid/vibid.h>

#include "../support/example1_model.h"

typedef struct row_buf {
    double theta[3], se[3], cov[9], f[2], fse[2], z[2], zse[2];
    unsigned pq[3], pi[3], mi[2];
    vibid_report_row_out out;
} row_buf;

static void row_init(row_buf *b)
{
    memset(b, 0, sizeof *b);
    b->out.theta = b->theta;
    b->out.se = b->se;
    b->out.cov = b->cov;
    b->out.freq = b->f;
    b->out.freq_se = b->fse;
    b->out.zeta = b->z;
    b->out.zeta_se = b->zse;
    b->out.param_quality = b->pq;
    b->out.param_implausible = b->pi;
    b->out.mode_implausible = b->mi;
}

/* An RLS identification whose estimate is its prior (zero samples move nothing). */
static vibid_ident *prior_ident(const vibid_model *m, const double *theta0)
{
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, 1e-3);
    cfg.estimator = VIBID_ESTIMATOR_RLS;
    cfg.rls_alpha = 1.0; /* a fixed prior: no samples collected to scale it */
    vibid_ident *id = vibid_ident_create(m, &cfg);
    assert_non_null(id);
    assert_int_equal(vibid_ident_set_prior(id, theta0, NULL), VIBID_OK);
    const double zero[3] = {0, 0, 0};
    for (int k = 0; k < 8; k++)
        assert_int_equal(vibid_ident_push(id, zero), VIBID_OK);
    return id;
}

static void test_rules_and_unstable_both_reported(void **state)
{
    (void)state;
    vibid_model *m = example1_model(0);
    vibid_report *rep = vibid_report_create(m, 1e-3);
    assert_non_null(rep);
    /* a negative damper (rule) and a negative spring to the base (unstable) */
    const double bad[3] = {2.5e5, -3.0, -18981.0};
    vibid_ident *id = prior_ident(m, bad);
    row_buf b;
    row_init(&b);
    assert_int_equal(vibid_report_row(rep, id, &b.out), VIBID_OK);
    if (b.out.est_status != VIBID_OK)
        fail_msg("no estimate: %s", b.out.message);
    assert_true(b.theta[1] == -3.0);
    assert_true(b.out.flags & VIBID_ROW_IMPLAUSIBLE);
    assert_true(b.out.implausible & VIBID_IMPLAUSIBLE_DAMPING);
    assert_true(b.pi[1] & VIBID_IMPLAUSIBLE_DAMPING);
    const char *rule = strstr(b.out.why, "d = -3"), *unstable = strstr(b.out.why, "unstable");
    if (!rule || !unstable || unstable < rule)
        fail_msg("the rules' finding, then the unstable message: %s", b.out.why);
    assert_string_equal(b.out.message, "");
    vibid_ident_destroy(id);

    /* plausible and stable: no P, no why */
    const double good[3] = {2.5e5, 300.0, 1.5e6};
    id = prior_ident(m, good);
    assert_int_equal(vibid_report_row(rep, id, &b.out), VIBID_OK);
    assert_int_equal(b.out.flags & VIBID_ROW_IMPLAUSIBLE, 0);
    assert_int_equal(b.out.implausible, 0);
    assert_string_equal(b.out.why, "");
    assert_true(b.f[0] > 0.0 && b.f[0] < b.f[1]);
    assert_true(b.out.flags & VIBID_ROW_SE_INVALID); /* RLS: textbook standard errors */
    vibid_ident_destroy(id);
    vibid_report_destroy(rep);
    vibid_model_destroy(m);
}

static void test_no_estimate_and_errors(void **state)
{
    (void)state;
    vibid_model *m = example1_model(0);
    vibid_report *rep = vibid_report_create(m, 1e-3);
    assert_non_null(rep);
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, 1e-3);
    cfg.estimator = VIBID_ESTIMATOR_LS;
    vibid_ident *id = vibid_ident_create(m, &cfg);
    assert_non_null(id);
    row_buf b;
    row_init(&b);
    assert_int_equal(vibid_report_row(rep, id, &b.out), VIBID_OK);
    assert_int_equal(b.out.est_status, VIBID_E_INSUFFICIENT_DATA);
    assert_int_equal(b.out.flags, VIBID_ROW_NOEST);
    assert_true(isnan(b.theta[0]) && isnan(b.f[1]) && isnan(b.cov[8]));
    assert_non_null(strstr(b.out.message, "vibid_ident_estimate"));

    assert_null(vibid_report_create(m, 0.0));
    assert_non_null(strstr(vibid_last_error(), "sample_time"));
    assert_int_equal(vibid_report_row(rep, NULL, &b.out), VIBID_E_NULL_ARGUMENT);
    b.out.zeta = NULL;
    assert_int_equal(vibid_report_row(rep, id, &b.out), VIBID_E_NULL_ARGUMENT);
    row_init(&b);
    /* an identification of another model (two parameters, not three) */
    vibid_model *m2 = vibid_model_create();
    size_t n1 = 0;
    assert_int_equal(vibid_model_add_node(m2, "m", 1.0, 0, &n1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m2, "k", VIBID_ELEMENT_SPRING, n1, VIBID_BASE, 1e4, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m2, "d", VIBID_ELEMENT_DAMPER, n1, VIBID_BASE, 5.0, 1), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m2, n1, VIBID_MEASURE_DISPLACEMENT), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m2, VIBID_BASE, VIBID_MEASURE_DISPLACEMENT), VIBID_OK);
    assert_int_equal(vibid_model_finalize(m2), VIBID_OK);
    vibid_ident *id2 = vibid_ident_create(m2, &cfg);
    assert_non_null(id2);
    assert_int_equal(vibid_report_row(rep, id2, &b.out), VIBID_E_DIMENSION);
    vibid_ident_destroy(id2);
    vibid_model_destroy(m2);

    assert_int_equal(vibid_report_no_estimate(rep, VIBID_E_STATE, &b.out), VIBID_OK);
    assert_int_equal(b.out.est_status, VIBID_E_STATE);
    assert_int_equal(b.out.flags, VIBID_ROW_NOEST);
    assert_null(vibid_report_reference(NULL));
    assert_int_equal(vibid_report_reference(rep)->n_modes, 2);
    vibid_ident_destroy(id);
    vibid_report_destroy(rep);
    vibid_report_destroy(NULL);
    vibid_model_destroy(m);
}

/* vibid_report_estimate: an estimate made elsewhere (vibidd's output-error rows) gets the
 * same checks as vibid_report_row's on the same numbers: identical modes, findings and
 * flags; the caller's quality becomes the U flag; a non-finite se adds I. */
static void test_estimate_made_elsewhere(void **state)
{
    (void)state;
    vibid_model *m = example1_model(0);
    vibid_report *rep = vibid_report_create(m, 1e-3);
    assert_non_null(rep);
    const double bad[3] = {2.5e5, -3.0, -18981.0};
    vibid_ident *id = prior_ident(m, bad);
    row_buf a, b;
    row_init(&a);
    row_init(&b);
    assert_int_equal(vibid_report_row(rep, id, &a.out), VIBID_OK);
    char why_a[1024];
    strcpy(why_a, a.out.why);
    assert_int_equal(vibid_report_estimate(rep, a.theta, a.se, a.cov, a.out.quality, 8, &b.out), VIBID_OK);
    assert_memory_equal(a.theta, b.theta, sizeof a.theta);
    assert_memory_equal(a.f, b.f, sizeof a.f);
    assert_memory_equal(a.z, b.z, sizeof a.z);
    assert_memory_equal(a.fse, b.fse, sizeof a.fse);
    assert_int_equal(a.out.flags, b.out.flags);
    assert_int_equal(a.out.implausible, b.out.implausible);
    assert_string_equal(why_a, b.out.why);
    /* no covariance: modes without standard errors; quality 0 and an inf se: I, no U */
    const double se[3] = {1.0, INFINITY, 2.0};
    const double good[3] = {2.5e5, 300.0, 1.5e6};
    assert_int_equal(vibid_report_estimate(rep, good, se, NULL, 0, 100, &b.out), VIBID_OK);
    assert_int_equal(b.out.flags, VIBID_ROW_NOT_EXCITED);
    assert_true(b.pq[1] & VIBID_QUALITY_NOT_EXCITED);
    assert_int_equal(b.pq[0], 0);
    assert_true(isnan(b.fse[0]) && isfinite(b.f[0]));
    assert_true(b.out.n_samples == 100);
    assert_int_equal(vibid_report_estimate(rep, good, a.se, NULL, VIBID_QUALITY_SE_INVALID, 100, &b.out), VIBID_OK);
    assert_int_equal(b.out.flags, VIBID_ROW_SE_INVALID);
    assert_int_equal(vibid_report_estimate(rep, NULL, se, NULL, 0, 0, &b.out), VIBID_E_NULL_ARGUMENT);
    vibid_ident_destroy(id);
    vibid_report_destroy(rep);
    vibid_model_destroy(m);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_rules_and_unstable_both_reported),
        cmocka_unit_test(test_no_estimate_and_errors),
        cmocka_unit_test(test_estimate_made_elsewhere),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
