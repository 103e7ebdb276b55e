/* CSV capture reader: header, good rows with exact values, every kind of bad row
 * reported with file:line and skipped. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include <cmocka.h>
#include <vibid_drivers/csv_capture.h>

static void test_rows_and_faults(void **state)
{
    (void)state;
    static const char csv[] = "# written by a test\n"
                              " t , u1,y1\n"
                              "0,0.5,-1e-3\n"
                              "0.001,nan,1\n"       /* NaN: bad */
                              "0.002,1,2,3\n"       /* extra field */
                              "0.003,1\n"           /* missing field */
                              "0.004,abc,1\n"       /* text */
                              "\n"
                              "0.005, 2.5 ,3\r\n";  /* spaces, CRLF: fine */
    vibid_drv_error err = {0};
    vibid_csv_reader *r = vibid_csv_open_mem(csv, sizeof csv - 1, "cap.csv", &err);
    assert_non_null(r);
    assert_int_equal(vibid_csv_column_count(r), 3);
    assert_string_equal(vibid_csv_column_name(r, 0), "t");
    assert_int_equal(vibid_csv_find_column(r, "y1"), 2);
    double v[3];
    unsigned long line;
    assert_int_equal(vibid_csv_next(r, v, &line, &err), VIBID_DRV_OK);
    assert_int_equal(line, 3);
    assert_true(v[0] == 0.0 && v[1] == 0.5 && v[2] == -1e-3); /* strtod is exact-rounding */
    const char *expect[] = {"cap.csv:4: column 'u1': non-finite", "cap.csv:5: more than 3 fields",
                            "cap.csv:6: 2 fields, the header has 3", "cap.csv:7: column 'u1': 'abc' is not a number"};
    for (size_t i = 0; i < 4; i++) {
        assert_int_equal(vibid_csv_next(r, v, &line, &err), VIBID_DRV_E_SYNTAX);
        if (!strstr(err.text, expect[i]))
            fail_msg("expected '%s', got '%s'", expect[i], err.text);
    }
    assert_int_equal(vibid_csv_next(r, v, &line, &err), VIBID_DRV_OK);
    assert_int_equal(line, 9);
    assert_true(v[1] == 2.5 && v[2] == 3.0);
    assert_int_equal(vibid_csv_next(r, v, &line, &err), VIBID_DRV_E_EOF);
    vibid_csv_stats st;
    vibid_csv_stats_get(r, &st);
    assert_int_equal(st.rows, 2);
    assert_int_equal(st.bad_rows, 4);
    vibid_csv_close(r);
}

/* A UTF-8 byte order mark before the first line (a spreadsheet's CSV export) is not part of
 * the first column's name, whether the first line is the header or a comment; elsewhere it
 * is data like any other bytes. */
static void test_byte_order_mark(void **state)
{
    (void)state;
    vibid_drv_error err = {0};
    static const char bom_header[] = "\xEF\xBB\xBFt,x\n0,1.5\n";
    vibid_csv_reader *r = vibid_csv_open_mem(bom_header, sizeof bom_header - 1, "b.csv", &err);
    assert_non_null(r);
    assert_string_equal(vibid_csv_column_name(r, 0), "t");
    double v[2];
    unsigned long line;
    assert_int_equal(vibid_csv_next(r, v, &line, &err), VIBID_DRV_OK);
    assert_true(v[0] == 0.0 && v[1] == 1.5);
    vibid_csv_close(r);
    static const char bom_comment[] = "\xEF\xBB\xBF# exported\nt,x\n";
    r = vibid_csv_open_mem(bom_comment, sizeof bom_comment - 1, "c.csv", &err);
    assert_non_null(r);
    assert_int_equal(vibid_csv_find_column(r, "t"), 0);
    vibid_csv_close(r);
    static const char bom_later[] = "t,x\n\xEF\xBB\xBF" "0,1\n";
    r = vibid_csv_open_mem(bom_later, sizeof bom_later - 1, "d.csv", &err);
    assert_non_null(r);
    assert_int_equal(vibid_csv_next(r, v, &line, &err), VIBID_DRV_E_SYNTAX); /* not at the file's start */
    vibid_csv_close(r);
}

static void test_bad_headers(void **state)
{
    (void)state;
    vibid_drv_error err = {0};
    assert_null(vibid_csv_open_mem("", 0, "e.csv", &err));
    assert_non_null(strstr(err.text, "e.csv: empty file"));
    assert_null(vibid_csv_open_mem("t,,y\n", 5, "e.csv", &err));
    assert_non_null(strstr(err.text, "e.csv:1: header column 2 has no name"));
    assert_null(vibid_csv_open_mem("t,y,t\n", 6, "e.csv", &err));
    assert_non_null(strstr(err.text, "appears twice"));
    assert_null(vibid_csv_open("/nonexistent.csv", &err));
    assert_int_equal(err.status, VIBID_DRV_E_IO);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_rows_and_faults),
        cmocka_unit_test(test_byte_order_mark),
        cmocka_unit_test(test_bad_headers),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
