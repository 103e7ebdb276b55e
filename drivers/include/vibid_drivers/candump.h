/* vibid_drivers/candump.h: can-utils candump log files (`candump -l`), read and write.
 *
 * A line is "(SECONDS.FRACTION) IFACE FRAME[ R| T]":
 *  - SECONDS: decimal (candump writes 10 digits, zero padded); FRACTION: exactly 6
 *    (microseconds, candump/canplayer) or 9 (nanoseconds) digits;
 *  - IFACE: interface name, possibly right-aligned with extra spaces (candump pads the
 *    names when it logs several interfaces);
 *  - FRAME, as can-utils' lib.c prints it: "123#DATA" (3 hex digits: 11-bit id),
 *    "12345678#DATA" (8 hex digits: 29-bit id, or an error frame when bit 0x20000000
 *    is set), "123#R" / "123#R5" (remote request, optional length digit), and CAN FD
 *    "123##<flags nibble><DATA>" (any nibble 0..F); DATA is hex bytes, optionally
 *    separated by '.', at most 8 (classic) or 64 (FD) bytes;
 *  - an optional trailing " R" (received) or " T" (transmitted) from `candump -x`.
 * Lines "DROPCOUNT: dropped N CAN frame(s) on 'IFACE' socket (total drops M)" report
 * frames the kernel dropped while candump was logging. Empty lines are ignored.
 * Anything else is a bad line: reported with file:line and counted, never fatal.
 */
#ifndef VIBID_DRIVERS_CANDUMP_H
#define VIBID_DRIVERS_CANDUMP_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include <vibid_drivers/can_frame.h>
#include <vibid_drivers/status.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef enum vibid_candump_kind {
    VIBID_CANDUMP_FRAME = 0,     /* entry.frame is valid */
    VIBID_CANDUMP_DROPCOUNT = 1, /* entry.dropped / entry.total_drops valid */
    VIBID_CANDUMP_BAD_LINE = 2,  /* entry.text says what is wrong and where */
    VIBID_CANDUMP_EMPTY = 3      /* blank line (parse_line only; the reader skips them) */
} vibid_candump_kind;

typedef struct vibid_candump_entry {
    vibid_candump_kind kind;
    unsigned long line;          /* 1-based line number in the file */
    vibid_can_frame frame;
    uint32_t dropped, total_drops;
    char text[192];              /* BAD_LINE: "file:line: reason" */
} vibid_candump_entry;

/* Parses one line (without its '\n'; it may contain NUL bytes, which are errors).
 * Pure function, no allocation. On a bad line entry->text holds the reason only
 * (without file:line). Returns entry->kind. */
vibid_candump_kind vibid_candump_parse_line(const char *line, size_t len, vibid_candump_entry *entry);

/* Formats a frame as candump -l does, without the '\n':
 * "(%010llu.%06llu) IFACE FRAME" (classic data upper-case hex without separators,
 * RTR "R" or "R<len>", FD "##<nibble>", error frames with 8 hex digits incl.
 * 0x20000000). The timestamp is truncated to microseconds, as candump does.
 * t_ns must be >= 0. Returns the length written (excluding NUL) or -1 if cap is too
 * small (256 bytes are always enough) or the frame is invalid. */
int vibid_candump_format(char *buf, size_t cap, const vibid_can_frame *frame, const char *iface);

/* ---- reader ---- */
typedef struct vibid_candump_reader vibid_candump_reader;

typedef struct vibid_candump_stats {
    uint64_t lines;       /* lines read, including bad and empty ones */
    uint64_t frames;      /* data, RTR and error frames returned */
    uint64_t error_frames;/* of which error frames */
    uint64_t bad_lines;   /* lines reported as BAD_LINE */
    uint64_t drop_lines;  /* DROPCOUNT lines */
    uint64_t dropped;     /* sum of the frames those lines say were dropped */
} vibid_candump_stats;

/* Opens a log file. NULL on failure (err says why). */
vibid_candump_reader *vibid_candump_reader_open(const char *path, vibid_drv_error *err);
/* Reads from memory (the reader keeps a pointer: data must outlive it); `name` is
 * used in messages. */
vibid_candump_reader *vibid_candump_reader_open_mem(const char *data, size_t len, const char *name,
                                                    vibid_drv_error *err);
/* Next entry: VIBID_DRV_OK with *entry filled (FRAME, DROPCOUNT or BAD_LINE; the
 * reader continues after a bad line), VIBID_DRV_E_EOF at the end, VIBID_DRV_E_IO on a
 * read error (entry->text says which). */
vibid_drv_status vibid_candump_reader_next(vibid_candump_reader *r, vibid_candump_entry *entry);
void vibid_candump_reader_stats(const vibid_candump_reader *r, vibid_candump_stats *stats);
void vibid_candump_reader_close(vibid_candump_reader *r);

/* ---- writer ---- */
typedef struct vibid_candump_writer vibid_candump_writer;

/* Creates (truncates) or appends to path. Output is buffered; see flush. */
vibid_candump_writer *vibid_candump_writer_open(const char *path, bool append, vibid_drv_error *err);
/* Writes one frame line. iface NULL means frame->iface. */
vibid_drv_status vibid_candump_writer_write(vibid_candump_writer *w, const vibid_can_frame *frame,
                                            const char *iface, vibid_drv_error *err);
/* Writes a DROPCOUNT line exactly as candump does. */
vibid_drv_status vibid_candump_writer_dropcount(vibid_candump_writer *w, uint32_t dropped,
                                                uint32_t total, const char *iface,
                                                vibid_drv_error *err);
/* Pushes buffered lines to the kernel (fflush); with sync also fdatasync. */
vibid_drv_status vibid_candump_writer_flush(vibid_candump_writer *w, bool sync, vibid_drv_error *err);
/* Flushes and closes; returns the first error seen (writes are checked). NULL-safe. */
vibid_drv_status vibid_candump_writer_close(vibid_candump_writer *w, vibid_drv_error *err);

#ifdef __cplusplus
}
#endif
#endif
