/* The source abstraction and its test double: batching, EOF/AGAIN, scripted failure,
 * record and jitter statistics, NULL safety, the fault kinds' names. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include <cmocka.h>
#include <vibid_drivers/source.h>

static vibid_source_double_config script(vibid_record *recs)
{
    vibid_source_double_config cfg;
    memset(&cfg, 0, sizeof cfg);
    cfg.chanmap.n = 1;
    strcpy(cfg.chanmap.ch[0].name, "x");
    /* samples 0..4 at 1 ms, 2 ms, 3 ms, 5 ms, 6 ms (3->5: 2 ms interval), a gap, a fault */
    static const int64_t t_ms[] = {1, 2, 3, 5, 6};
    size_t n = 0;
    for (int k = 0; k < 5; k++) {
        memset(&recs[n], 0, sizeof recs[n]);
        recs[n].kind = VIBID_REC_SAMPLE;
        recs[n].index = (uint64_t)k;
        recs[n].t_ns = t_ms[k] * 1000000;
        recs[n].n_values = 1;
        recs[n].values[0] = 0.5 * k;
        n++;
    }
    memset(&recs[n], 0, sizeof recs[n]);
    recs[n].kind = VIBID_REC_GAP;
    recs[n].index = 5;
    recs[n].count = 3;
    n++;
    memset(&recs[n], 0, sizeof recs[n]);
    recs[n].kind = VIBID_REC_FAULT;
    recs[n].fault = VIBID_FAULT_POLL;
    n++;
    cfg.records = recs;
    cfg.n_records = n;
    return cfg;
}

static void test_double_batches_and_stats(void **state)
{
    (void)state;
    vibid_record recs[8], out[4];
    vibid_source_double_config cfg = script(recs);
    cfg.max_batch = 3;
    vibid_drv_error err = {0};
    vibid_source *s = vibid_source_open(&vibid_source_double_ops, &cfg, &err);
    assert_non_null(s);
    memset(recs, 0, sizeof recs); /* the source copied the script */
    assert_string_equal(vibid_source_kind(s), "double");
    assert_string_equal(vibid_source_channels(s)->ch[0].name, "x");
    size_t n, total = 0;
    size_t sizes[3];
    for (int i = 0; i < 3; i++) {
        assert_int_equal(vibid_source_read(s, out, 4, &n, 0, &err), VIBID_DRV_OK);
        sizes[i] = n;
        for (size_t j = 0; j < n; j++, total++)
            if (total < 5)
                assert_true(out[j].kind == VIBID_REC_SAMPLE && out[j].values[0] == 0.5 * (double)total);
    }
    assert_int_equal(sizes[0], 3);
    assert_int_equal(sizes[1], 3);
    assert_int_equal(sizes[2], 1);
    assert_int_equal(vibid_source_read(s, out, 4, &n, 0, &err), VIBID_DRV_E_EOF);
    assert_int_equal(n, 0);
    vibid_source_stats st;
    vibid_source_stats_get(s, &st);
    assert_int_equal(st.samples, 5);
    assert_int_equal(st.gaps, 1);
    assert_int_equal(st.missing_samples, 3);
    assert_int_equal(st.faults, 1);
    /* intervals 1,1,2,1 ms: mean 1.25 ms, sample std sqrt(0.75/3) = 0.5 ms, min 1, max 2 */
    assert_int_equal(st.jitter.n, 4);
    assert_true(fabs(st.jitter.mean_s - 1.25e-3) < 1e-15);
    assert_true(fabs(st.jitter.std_s - 0.5e-3) < 1e-15);
    assert_true(st.jitter.min_s == 1e-3 && st.jitter.max_s == 2e-3);
    vibid_source_close(s);
    vibid_source_close(NULL);
}

static void test_double_endless_and_failure(void **state)
{
    (void)state;
    vibid_record recs[8], out[16];
    vibid_source_double_config cfg = script(recs);
    cfg.endless = true;
    cfg.fail_after_reads = 3;
    cfg.fail_status = VIBID_DRV_E_LINK;
    vibid_drv_error err = {0};
    vibid_source *s = vibid_source_open(&vibid_source_double_ops, &cfg, &err);
    assert_non_null(s);
    size_t n;
    assert_int_equal(vibid_source_read(s, out, 16, &n, 0, &err), VIBID_DRV_OK);
    assert_int_equal(n, 7);
    assert_int_equal(vibid_source_read(s, out, 16, &n, 0, &err), VIBID_DRV_E_AGAIN);
    assert_int_equal(vibid_source_read(s, out, 16, &n, 0, &err), VIBID_DRV_E_LINK);
    assert_non_null(strstr(err.text, "scripted failure on read #3"));
    assert_int_equal(vibid_source_read(s, out, 16, &n, 0, &err), VIBID_DRV_E_AGAIN);
    /* bad arguments are errors, not crashes */
    assert_int_equal(vibid_source_read(s, out, 0, &n, 0, &err), VIBID_DRV_E_ARG);
    assert_int_equal(vibid_source_read(NULL, out, 1, &n, 0, &err), VIBID_DRV_E_ARG);
    vibid_source_close(s);
    assert_null(vibid_source_open(&vibid_source_double_ops, NULL, &err));
    assert_int_equal(err.status, VIBID_DRV_E_ARG);
    cfg.records = NULL;
    assert_null(vibid_source_open(&vibid_source_double_ops, &cfg, &err));
    assert_non_null(strstr(err.text, "records is NULL"));
    assert_null(vibid_source_open(NULL, &cfg, &err));
}

/* The names are an interface (vibidd's status file faults_<name>, its metrics' kind label,
 * the Python fault tables' "kind"): every one is pinned here, so that a renamed or reordered
 * code fails this test rather than a user's dashboard. */
static void test_fault_names(void **state)
{
    (void)state;
    static const char *const want[] = {"none",      "bad_line", "unknown_id", "short_frame", "nonfinite",
                                       "duplicate", "late",     "bus_error",  "dropped",     "poll",
                                       "link",      "corrupt",  "clock"};
    assert_int_equal(sizeof want / sizeof want[0], VIBID_FAULT_LAST + 1);
    for (unsigned c = 0; c <= VIBID_FAULT_LAST; c++)
        assert_string_equal(vibid_fault_name((vibid_fault_code)c), want[c]);
    assert_string_equal(vibid_fault_name(VIBID_FAULT_POLL), "poll");
    /* a code outside the enum (a newer writer, a corrupt record) gets the fixed "fault" */
    assert_string_equal(vibid_fault_name((vibid_fault_code)(VIBID_FAULT_LAST + 1)), "fault");
    assert_string_equal(vibid_fault_name((vibid_fault_code)-1), "fault");
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_double_batches_and_stats),
        cmocka_unit_test(test_double_endless_and_failure),
        cmocka_unit_test(test_fault_names),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
