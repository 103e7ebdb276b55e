/* vibid_drivers/csv_capture.h: CSV capture files with a header row, as vibid-sim and
 * spreadsheet users write them: "t,u1,y1,y2\n0,0.5,1e-3,2e-3\n...".
 *
 * - The first non-comment line is the header: comma-separated column names (spaces
 *   around a name are trimmed; names are non-empty and unique; 1..64 columns).
 * - Lines starting with '#' and blank lines are skipped (not counted as faults).
 * - Every data row must have exactly as many fields as the header, each a finite
 *   decimal number (strtod syntax in the "C" locale). Anything else (missing or extra
 *   fields, text, NaN, Inf, over-long lines, NUL bytes) is a bad row: reported with
 *   file:line and the column, counted, and skipped; the reader continues.
 */
#ifndef VIBID_DRIVERS_CSV_CAPTURE_H
#define VIBID_DRIVERS_CSV_CAPTURE_H

#include <stddef.h>
#include <stdint.h>

#include <vibid_drivers/status.h>

#ifdef __cplusplus
extern "C" {
#endif

#define VIBID_CSV_MAX_COLUMNS 64

typedef struct vibid_csv_reader vibid_csv_reader;

typedef struct vibid_csv_stats {
    uint64_t lines;    /* lines read (header, comments and blanks included) */
    uint64_t rows;     /* good data rows returned */
    uint64_t bad_rows; /* rows reported as bad */
} vibid_csv_stats;

/* Opens the file and reads its header. NULL on failure (I/O error, no header, bad
 * header: err names file:line and the problem). */
vibid_csv_reader *vibid_csv_open(const char *path, vibid_drv_error *err);
/* Same over memory; data must outlive the reader. */
vibid_csv_reader *vibid_csv_open_mem(const char *data, size_t len, const char *name, vibid_drv_error *err);
void vibid_csv_close(vibid_csv_reader *r);

size_t vibid_csv_column_count(const vibid_csv_reader *r);
/* Column name (lives as long as the reader); NULL when i is out of range. */
const char *vibid_csv_column_name(const vibid_csv_reader *r, size_t i);
/* Index of a column by exact name, or -1. */
int vibid_csv_find_column(const vibid_csv_reader *r, const char *name);

/* Next data row into values[0 .. column_count-1] (caller array).
 * VIBID_DRV_OK: row read (*line = its line number).
 * VIBID_DRV_E_SYNTAX: bad row, skipped; err->text = "file:line: reason" (values untouched).
 * VIBID_DRV_E_EOF: end of file. VIBID_DRV_E_IO: read error. No allocation. */
vibid_drv_status vibid_csv_next(vibid_csv_reader *r, double *values, unsigned long *line,
                                vibid_drv_error *err);
void vibid_csv_stats_get(const vibid_csv_reader *r, vibid_csv_stats *stats);

#ifdef __cplusplus
}
#endif
#endif
