/* The capture-format registry (vibid_drivers/capture_format.h): names and aliases,
 * extensions, recognition by content (the first bytes of MDF4, TDMS, candump -l, CSV and
 * vibidd's own recordings), files judged by content before extension, and the replay
 * source's resolution (a format vibidd does not replay is refused naming `vibid convert`). */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>
#include <vibid_drivers/capture_format.h>
#include <vibid_drivers/source_replay.h>

#include "support/drv_test_util.h"

static vibid_capture_format sniff(const char *text, size_t len)
{
    return vibid_capture_format_sniff((const unsigned char *)text, len);
}
#define SNIFF(lit) sniff(lit, sizeof(lit) - 1)

static void test_table_and_names(void **state)
{
    (void)state;
    size_t n = 0;
    const vibid_capture_format_info *t = vibid_capture_formats(&n);
    assert_int_equal(n, 4);
    for (size_t i = 0; i < n; i++) {
        assert_ptr_equal(vibid_capture_format_info_of(t[i].format), &t[i]);
        assert_int_equal(vibid_capture_format_by_name(t[i].name), t[i].format);
    }
    assert_int_equal(vibid_capture_format_by_name("CSV"), VIBID_CAPTURE_CSV);
    assert_int_equal(vibid_capture_format_by_name("mf4"), VIBID_CAPTURE_MDF);
    assert_int_equal(vibid_capture_format_by_name("MDF4"), VIBID_CAPTURE_MDF);
    assert_int_equal(vibid_capture_format_by_name("mdf"), VIBID_CAPTURE_MDF);
    assert_int_equal(vibid_capture_format_by_name("md"), VIBID_CAPTURE_UNKNOWN);   /* no prefix match */
    assert_int_equal(vibid_capture_format_by_name("mf4 "), VIBID_CAPTURE_UNKNOWN); /* no word match */
    assert_int_equal(vibid_capture_format_by_name(""), VIBID_CAPTURE_UNKNOWN);
    assert_int_equal(vibid_capture_format_by_name(NULL), VIBID_CAPTURE_UNKNOWN);
    assert_null(vibid_capture_format_info_of(VIBID_CAPTURE_UNKNOWN));
    assert_null(vibid_capture_format_info_of((vibid_capture_format)99));
    /* the replay enum's values are the registry's (source_replay.h relies on it) */
    assert_int_equal((int)VIBID_CAPTURE_CSV, (int)VIBID_REPLAY_CSV);
    assert_int_equal((int)VIBID_CAPTURE_CANDUMP, (int)VIBID_REPLAY_CANDUMP);
    char list[256];
    assert_string_equal(vibid_capture_format_list(list, sizeof list, true), "candump (.log), csv (.csv)");
    assert_string_equal(vibid_capture_format_list(list, sizeof list, false),
                        "candump (.log), csv (.csv), mdf (.mf4 .mdf), tdms (.tdms)");
    char small[8];
    vibid_capture_format_list(small, sizeof small, false); /* truncated, terminated */
    assert_true(strlen(small) < sizeof small);
}

static void test_extensions(void **state)
{
    (void)state;
    assert_int_equal(vibid_capture_format_by_extension("a/b/run7.CSV"), VIBID_CAPTURE_CSV);
    assert_int_equal(vibid_capture_format_by_extension("run7.mf4"), VIBID_CAPTURE_MDF);
    assert_int_equal(vibid_capture_format_by_extension("run7.MDF"), VIBID_CAPTURE_MDF);
    assert_int_equal(vibid_capture_format_by_extension("run7.tdms"), VIBID_CAPTURE_TDMS);
    assert_int_equal(vibid_capture_format_by_extension("candump-2026.log"), VIBID_CAPTURE_CANDUMP);
    assert_int_equal(vibid_capture_format_by_extension("run7.txt"), VIBID_CAPTURE_UNKNOWN);
    assert_int_equal(vibid_capture_format_by_extension("dir.csv/run7"), VIBID_CAPTURE_UNKNOWN);
    assert_int_equal(vibid_capture_format_by_extension("run7"), VIBID_CAPTURE_UNKNOWN);
    assert_int_equal(vibid_capture_format_by_extension(".csv.bak"), VIBID_CAPTURE_UNKNOWN);
}

static void test_sniff(void **state)
{
    (void)state;
    assert_int_equal(SNIFF("MDF     4.10    amdf4.1"), VIBID_CAPTURE_MDF);
    assert_int_equal(SNIFF("TDSm\x0e\x00\x00\x00"), VIBID_CAPTURE_TDMS);
    assert_int_equal(SNIFF("(1700000000.000000) can0 123#0011223344556677\n"), VIBID_CAPTURE_CANDUMP);
    assert_int_equal(SNIFF("t,x1,x2,s\n0,1,2,3\n"), VIBID_CAPTURE_CSV);
    assert_int_equal(SNIFF("\xEF\xBB\xBFt,x1\n"), VIBID_CAPTURE_CSV);
    assert_int_equal(SNIFF("# vibidd raw recording of stand 'x' at 2000 Hz\nt,x1,x2\n"), VIBID_CAPTURE_CSV);
    assert_int_equal(SNIFF("\n\n# comment\n(12.5) vcan0 1#00\n"), VIBID_CAPTURE_CANDUMP);
    assert_int_equal(SNIFF("(abc) can0\n"), VIBID_CAPTURE_UNKNOWN);
    assert_int_equal(SNIFF("hello world\n"), VIBID_CAPTURE_UNKNOWN);
    assert_int_equal(SNIFF("\x7f" "ELF\x02\x01,\x00"), VIBID_CAPTURE_UNKNOWN); /* control bytes: binary */
    assert_int_equal(sniff("ab,\0c\n", 6), VIBID_CAPTURE_UNKNOWN);
    assert_int_equal(SNIFF("# only a comment"), VIBID_CAPTURE_UNKNOWN);
    assert_int_equal(sniff("", 0), VIBID_CAPTURE_UNKNOWN);
    assert_int_equal(SNIFF("MDF"), VIBID_CAPTURE_UNKNOWN); /* too short to be the identification block */
}

static void test_files_and_replay_resolution(void **state)
{
    (void)state;
    char p[512], err[512];
    /* content wins over the name: a CSV named .log, a candump log named .txt */
    assert_non_null(drv_write_tmp("capfmt_csv.log", "t,x\n0,1\n", 8, p, sizeof p));
    assert_int_equal(vibid_capture_format_of_file(p), VIBID_CAPTURE_CSV);
    assert_int_equal(vibid_replay_format_resolve(VIBID_REPLAY_AUTO, p, err, sizeof err), VIBID_REPLAY_CSV);
    remove(p);
    assert_non_null(drv_write_tmp("capfmt_candump.txt", "(1.000000) can0 1#00\n", 21, p, sizeof p));
    assert_int_equal(vibid_capture_format_of_file(p), VIBID_CAPTURE_CANDUMP);
    assert_int_equal(vibid_replay_format_resolve(VIBID_REPLAY_AUTO, p, err, sizeof err), VIBID_REPLAY_CANDUMP);
    /* an explicit format is taken as given */
    assert_int_equal(vibid_replay_format_resolve(VIBID_REPLAY_CSV, p, err, sizeof err), VIBID_REPLAY_CSV);
    remove(p);
    /* an empty file and a missing one: the extension decides; nothing at all: candump */
    assert_non_null(drv_write_tmp("capfmt_empty.csv", "", 0, p, sizeof p));
    assert_int_equal(vibid_capture_format_of_file(p), VIBID_CAPTURE_CSV);
    remove(p);
    assert_int_equal(vibid_capture_format_of_file("/no/such/dir/cap.tdms"), VIBID_CAPTURE_TDMS);
    assert_int_equal(vibid_replay_format_resolve(VIBID_REPLAY_AUTO, "/no/such/file", err, sizeof err),
                     VIBID_REPLAY_CANDUMP);
    /* MDF4 under any name: refused, naming the file, the format, what vibidd replays and the way out */
    assert_non_null(drv_write_tmp("capfmt_mdf.dat", "MDF     4.10    ", 16, p, sizeof p));
    err[0] = '\0';
    assert_int_equal(vibid_replay_format_resolve(VIBID_REPLAY_AUTO, p, err, sizeof err), VIBID_REPLAY_AUTO);
    printf("  refused: %s\n", err);
    assert_non_null(strstr(err, p));
    assert_non_null(strstr(err, "ASAM MDF4"));
    assert_non_null(strstr(err, "candump (.log), csv (.csv)"));
    assert_non_null(strstr(err, "vibid convert"));
    remove(p);
    assert_non_null(drv_write_tmp("capfmt.tdms", "TDSm", 4, p, sizeof p));
    assert_int_equal(vibid_replay_format_resolve(VIBID_REPLAY_AUTO, p, err, sizeof err), VIBID_REPLAY_AUTO);
    assert_non_null(strstr(err, "NI TDMS"));
    remove(p);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_table_and_names),
        cmocka_unit_test(test_extensions),
        cmocka_unit_test(test_sniff),
        cmocka_unit_test(test_files_and_replay_resolution),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
