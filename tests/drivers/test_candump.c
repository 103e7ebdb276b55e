/* candump log reader and writer: every line variant of the issue, bad lines counted
 * with file:line, and the writer's exact bytes. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cmocka.h>
#include <vibid_drivers/candump.h>

static vibid_candump_kind p(const char *line, vibid_candump_entry *e)
{
    memset(e, 0, sizeof *e);
    return vibid_candump_parse_line(line, strlen(line), e);
}

static void test_variants(void **state)
{
    (void)state;
    vibid_candump_entry e;
    assert_int_equal(p("(1436509052.249713) vcan0 044#2A366C2BBA", &e), VIBID_CANDUMP_FRAME);
    assert_true(e.frame.t_ns == 1436509052249713000LL);
    assert_int_equal(e.frame.id, 0x44);
    assert_int_equal(e.frame.flags, 0);
    assert_int_equal(e.frame.len, 5);
    assert_int_equal(e.frame.data[4], 0xBA);
    assert_string_equal(e.frame.iface, "vcan0");
    /* 9-digit fraction, right-aligned interface name, ' T' direction */
    assert_int_equal(p("(1436509052.249713123)   can1 12345678#11.22 T", &e), VIBID_CANDUMP_FRAME);
    assert_true(e.frame.t_ns == 1436509052249713123LL);
    assert_int_equal(e.frame.flags, VIBID_CAN_F_EXT | VIBID_CAN_F_TX);
    assert_int_equal(e.frame.id, 0x12345678);
    assert_int_equal(e.frame.len, 2);
    /* CAN FD with every nibble value */
    for (int nib = 0; nib < 16; nib++) {
        char line[128];
        snprintf(line, sizeof line, "(0000000001.000001) vcan0 123##%X00112233445566778899AABB R", nib);
        assert_int_equal(p(line, &e), VIBID_CANDUMP_FRAME);
        assert_int_equal(e.frame.flags, VIBID_CAN_F_FD);
        assert_int_equal(e.frame.fd_flags, nib);
        assert_int_equal(e.frame.len, 12);
    }
    /* 64-byte FD payload */
    char big[256] = "(1.000000) c 1FFFFFFF##1";
    for (int i = 0; i < 64; i++)
        sprintf(big + strlen(big), "%02X", i);
    assert_int_equal(p(big, &e), VIBID_CANDUMP_FRAME);
    assert_int_equal(e.frame.len, 64);
    assert_int_equal(e.frame.data[63], 63);
    /* RTR, with and without length */
    assert_int_equal(p("(1.000000) vcan0 123#R", &e), VIBID_CANDUMP_FRAME);
    assert_int_equal(e.frame.flags, VIBID_CAN_F_RTR);
    assert_int_equal(e.frame.len, 0);
    assert_int_equal(p("(1.000000) vcan0 123#R5", &e), VIBID_CANDUMP_FRAME);
    assert_int_equal(e.frame.len, 5);
    /* error frame: bus-off class 0x40 */
    assert_int_equal(p("(1.000000) vcan0 20000040#0000000000000000", &e), VIBID_CANDUMP_FRAME);
    assert_int_equal(e.frame.flags, VIBID_CAN_F_ERR);
    assert_int_equal(e.frame.id, 0x40);
    /* DROPCOUNT */
    assert_int_equal(p("DROPCOUNT: dropped 3 CAN frames on 'vcan0' socket (total drops 10)", &e),
                     VIBID_CANDUMP_DROPCOUNT);
    assert_int_equal(e.dropped, 3);
    assert_int_equal(e.total_drops, 10);
    assert_int_equal(p("   ", &e), VIBID_CANDUMP_EMPTY);
    /* CRLF endings */
    assert_int_equal(p("(1.000000) vcan0 123#\r", &e), VIBID_CANDUMP_FRAME);
    assert_int_equal(e.frame.len, 0);
}

static void test_bad_lines(void **state)
{
    (void)state;
    static const char *bad[] = {
        "1436509052.249713 vcan0 044#2A",          /* no parentheses */
        "(1436509052.2497) vcan0 044#2A",          /* 4-digit fraction */
        "(1436509052.249713) vcan0 44#2A",         /* 2-digit id */
        "(1436509052.249713) vcan0 800#2A",        /* 11-bit id too large */
        "(1436509052.249713) vcan0 044#2A3",       /* odd hex digits */
        "(1436509052.249713) vcan0 044#112233445566778899", /* 9 classic bytes */
        "(1436509052.249713) vcan0 044##",         /* FD without nibble */
        "(1436509052.249713) vcan0 044##1001122334455667788", /* 9-byte FD: invalid length */
        "(1436509052.249713) vcan0 044#R9",        /* RTR length > 8 */
        "(1436509052.249713) vcan0 044#11 X",      /* junk after frame */
        "(1436509052.249713) vcan0",               /* no frame */
        "(99999999999999999999.000000) vcan0 044#11", /* seconds overflow */
        "(1436509052.249713) vcan0 G44#11",        /* non-hex id */
        "DROPCOUNT: dropped x CAN frames",
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        vibid_candump_entry e;
        if (p(bad[i], &e) != VIBID_CANDUMP_BAD_LINE)
            fail_msg("line accepted: %s", bad[i]);
        assert_true(strlen(e.text) > 5);
    }
    /* NUL inside a line */
    vibid_candump_entry e;
    memset(&e, 0, sizeof e);
    assert_int_equal(vibid_candump_parse_line("(1.000000) v 1\0#11", 18, &e), VIBID_CANDUMP_BAD_LINE);
}

static void test_reader_counts_and_locates(void **state)
{
    (void)state;
    static const char log[] = "(1.000000) vcan0 001#01\n"
                              "garbage line\n"
                              "\n"
                              "DROPCOUNT: dropped 2 CAN frames on 'vcan0' socket (total drops 2)\n"
                              "(2.000000) vcan0 002#02\n"
                              "(3.000000) vcan0 003#0"; /* truncated last line, no newline */
    vibid_drv_error err = {0};
    vibid_candump_reader *r = vibid_candump_reader_open_mem(log, sizeof log - 1, "mem.log", &err);
    assert_non_null(r);
    vibid_candump_entry e;
    assert_int_equal(vibid_candump_reader_next(r, &e), VIBID_DRV_OK);
    assert_int_equal(e.kind, VIBID_CANDUMP_FRAME);
    assert_int_equal(vibid_candump_reader_next(r, &e), VIBID_DRV_OK);
    assert_int_equal(e.kind, VIBID_CANDUMP_BAD_LINE);
    assert_non_null(strstr(e.text, "mem.log:2: "));
    assert_int_equal(vibid_candump_reader_next(r, &e), VIBID_DRV_OK);
    assert_int_equal(e.kind, VIBID_CANDUMP_DROPCOUNT);
    assert_int_equal(e.line, 4);
    assert_int_equal(vibid_candump_reader_next(r, &e), VIBID_DRV_OK);
    assert_int_equal(e.frame.id, 2);
    assert_int_equal(vibid_candump_reader_next(r, &e), VIBID_DRV_OK);
    assert_int_equal(e.kind, VIBID_CANDUMP_BAD_LINE);
    assert_non_null(strstr(e.text, "mem.log:6: "));
    assert_int_equal(vibid_candump_reader_next(r, &e), VIBID_DRV_E_EOF);
    assert_int_equal(vibid_candump_reader_next(r, &e), VIBID_DRV_E_EOF);
    vibid_candump_stats st;
    vibid_candump_reader_stats(r, &st);
    assert_int_equal(st.lines, 6);
    assert_int_equal(st.frames, 2);
    assert_int_equal(st.bad_lines, 2);
    assert_int_equal(st.dropped, 2);
    vibid_candump_reader_close(r);

    /* An over-long line is one bad line, and the reader goes on after it. */
    size_t n = 5000;
    char *huge = malloc(n + 64);
    memset(huge, 'A', n);
    strcpy(huge + n, "\n(1.000000) vcan0 001#01\n");
    r = vibid_candump_reader_open_mem(huge, strlen(huge), "huge.log", &err);
    assert_int_equal(vibid_candump_reader_next(r, &e), VIBID_DRV_OK);
    assert_int_equal(e.kind, VIBID_CANDUMP_BAD_LINE);
    assert_non_null(strstr(e.text, "huge.log:1: line longer"));
    assert_int_equal(vibid_candump_reader_next(r, &e), VIBID_DRV_OK);
    assert_int_equal(e.kind, VIBID_CANDUMP_FRAME);
    vibid_candump_reader_close(r);
    free(huge);
}

static void test_writer_exact_bytes(void **state)
{
    (void)state;
    char path[512];
    const char *tmp = getenv("VIBID_DRV_TMP");
    snprintf(path, sizeof path, "%s/test_candump_writer.log", tmp ? tmp : "/tmp");
    vibid_drv_error err = {0};
    vibid_candump_writer *w = vibid_candump_writer_open(path, false, &err);
    assert_non_null(w);
    vibid_can_frame f;
    memset(&f, 0, sizeof f);
    f.t_ns = 1436509052249713999LL; /* truncated to microseconds, as candump does */
    f.id = 0x44;
    f.len = 5;
    memcpy(f.data, "\x2A\x36\x6C\x2B\xBA", 5);
    assert_int_equal(vibid_candump_writer_write(w, &f, "vcan0", &err), VIBID_DRV_OK);
    f.t_ns = 5000000; /* zero-padded 10-digit seconds */
    f.flags = VIBID_CAN_F_EXT | VIBID_CAN_F_FD;
    f.fd_flags = 0x5;
    f.id = 0x1ABCDEF;
    f.len = 12;
    memset(f.data, 0xA5, 12);
    assert_int_equal(vibid_candump_writer_write(w, &f, "can10", &err), VIBID_DRV_OK);
    f.flags = VIBID_CAN_F_RTR;
    f.id = 0x7FF;
    f.len = 3;
    assert_int_equal(vibid_candump_writer_write(w, &f, "vcan0", &err), VIBID_DRV_OK);
    f.flags = VIBID_CAN_F_ERR;
    f.id = 0x4;
    f.len = 8;
    memset(f.data, 0, 8);
    f.data[1] = 0x01;
    assert_int_equal(vibid_candump_writer_write(w, &f, "vcan0", &err), VIBID_DRV_OK);
    assert_int_equal(vibid_candump_writer_dropcount(w, 1, 7, "vcan0", &err), VIBID_DRV_OK);
    /* invalid frames are refused, not written */
    f.flags = 0;
    f.len = 9;
    assert_int_equal(vibid_candump_writer_write(w, &f, "vcan0", &err), VIBID_DRV_E_ARG);
    assert_int_equal(vibid_candump_writer_close(w, &err), VIBID_DRV_OK);

    static const char expect[] =
        "(1436509052.249713) vcan0 044#2A366C2BBA\n"
        "(0000000000.005000) can10 01ABCDEF##5A5A5A5A5A5A5A5A5A5A5A5A5\n"
        "(0000000000.005000) vcan0 7FF#R3\n"
        "(0000000000.005000) vcan0 20000004#0001000000000000\n"
        "DROPCOUNT: dropped 1 CAN frame on 'vcan0' socket (total drops 7)\n";
    FILE *fp = fopen(path, "rb");
    assert_non_null(fp);
    char got[1024] = {0};
    size_t n = fread(got, 1, sizeof got - 1, fp);
    fclose(fp);
    assert_int_equal(n, strlen(expect));
    assert_string_equal(got, expect);
    remove(path);
}

/* The file reader reads 64 KiB chunks: lines across a chunk boundary, a line longer than a
 * chunk (cut and reported, the reader resynchronises at its newline), CRLF, a blank line
 * and an unterminated last line must come out exactly as from the in-memory reader. */
static void test_file_reader_chunks(void **state)
{
    (void)state;
    char path[] = "/tmp/vibid_candump_chunks_XXXXXX";
    int fd = mkstemp(path);
    assert_true(fd >= 0);
    FILE *f = fdopen(fd, "w");
    assert_non_null(f);
    const int n_before = 1500; /* 1500 lines of 46 bytes = 69 KB: one straddles the first chunk end */
    for (int i = 0; i < n_before; i++)
        fprintf(f, "(1700000000.%06d) vcan0 100#%016X\n", i, (unsigned)i);
    fputc('(', f); /* one line of 70,000 bytes: longer than a chunk */
    for (int i = 0; i < 70000; i++)
        fputc('7', f);
    fputs("\n(1700000001.000000) vcan0 101#11\r\n\n(1700000002.000000) vcan0 102#22", f);
    assert_int_equal(fclose(f), 0);

    vibid_drv_error err = {0};
    vibid_candump_reader *r = vibid_candump_reader_open(path, &err);
    assert_non_null(r);
    vibid_candump_entry e;
    for (int i = 0; i < n_before; i++) {
        assert_int_equal(vibid_candump_reader_next(r, &e), VIBID_DRV_OK);
        assert_int_equal(e.kind, VIBID_CANDUMP_FRAME);
        assert_int_equal((int)e.line, i + 1);
        assert_true(e.frame.t_ns == 1700000000000000000LL + 1000LL * i);
        assert_int_equal(e.frame.data[7], i & 0xFF);
        assert_int_equal(e.frame.data[6], (i >> 8) & 0xFF);
    }
    assert_int_equal(vibid_candump_reader_next(r, &e), VIBID_DRV_OK);
    assert_int_equal(e.kind, VIBID_CANDUMP_BAD_LINE);
    assert_int_equal((int)e.line, n_before + 1);
    assert_non_null(strstr(e.text, "line longer than"));
    assert_int_equal(vibid_candump_reader_next(r, &e), VIBID_DRV_OK); /* CRLF line */
    assert_int_equal(e.kind, VIBID_CANDUMP_FRAME);
    assert_int_equal((int)e.line, n_before + 2);
    assert_int_equal(e.frame.id, 0x101);
    assert_int_equal(e.frame.len, 1);
    assert_int_equal(vibid_candump_reader_next(r, &e), VIBID_DRV_OK); /* after the blank line */
    assert_int_equal((int)e.line, n_before + 4);
    assert_int_equal(e.frame.id, 0x102);
    assert_int_equal(e.frame.data[0], 0x22);
    assert_int_equal(vibid_candump_reader_next(r, &e), VIBID_DRV_E_EOF);
    assert_int_equal(vibid_candump_reader_next(r, &e), VIBID_DRV_E_EOF); /* stays at the end */
    vibid_candump_stats st;
    vibid_candump_reader_stats(r, &st);
    assert_int_equal(st.frames, n_before + 2);
    assert_int_equal(st.bad_lines, 1);
    vibid_candump_reader_close(r);
    unlink(path);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_variants),
        cmocka_unit_test(test_bad_lines),
        cmocka_unit_test(test_reader_counts_and_locates),
        cmocka_unit_test(test_writer_exact_bytes),
        cmocka_unit_test(test_file_reader_chunks),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
