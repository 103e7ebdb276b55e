/* Internal helpers for the file readers: whole-file reads with a size cap, and a
 * buffered line reader that never stalls or grows without bound on hostile input
 * (over-long lines are cut and flagged, NUL bytes are passed through for the caller
 * to reject, CR before LF is dropped). Not part of the public API. */
#ifndef VIBID_DRIVERS_FILE_UTIL_H
#define VIBID_DRIVERS_FILE_UTIL_H

#include <stdbool.h>
#include <stddef.h>
#include <stdio.h>

#include <vibid_drivers/status.h>

/* Reads all of path (at most max bytes) into a NUL-terminated malloc'd buffer. */
char *vibid_read_whole_file(const char *path, size_t max, size_t *len, vibid_drv_error *err);

#define VIBID_LINE_MAX 1024    /* longest line kept; longer ones are flagged too_long */
#define VIBID_LINE_CHUNK 65536 /* file mode reads this many bytes at a time (one fread per ~1500
                                  candump lines instead of one getc per byte) */

typedef struct vibid_line_reader {
    FILE *fp;             /* file mode; NULL in memory mode */
    const char *mem;      /* memory mode */
    size_t mem_len, mem_pos;
    unsigned long line;   /* number of the line last returned, 1-based */
    size_t pos, end;      /* file mode: unread bytes are chunk[pos, end) */
    /* +16: room for the NUL after a last unterminated line, and for the newline search's
     * 16-byte loads, which may reach up to 15 bytes past the data (never past the array) */
    char chunk[VIBID_LINE_CHUNK + 16];
    char buf[VIBID_LINE_MAX + 1];     /* cut lines and memory-mode lines are copied here */
} vibid_line_reader;

void vibid_line_reader_init_file(vibid_line_reader *lr, FILE *fp);
void vibid_line_reader_init_mem(vibid_line_reader *lr, const char *data, size_t len);
/* 1: a line in *line (NUL-terminated, without '\n' and trailing '\r'), *len its
 * length (it may hold NUL bytes); *too_long set when the line was cut.
 * 0: end of input. -1: read error (errno set). */
int vibid_line_reader_next(vibid_line_reader *lr, const char **line, size_t *len, bool *too_long);

#endif
