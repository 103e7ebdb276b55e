/* vibid_drivers/capture_format.h: the one table of capture-file formats - names, file-name
 * extensions, how to recognise a file by its first bytes, and which programs read it - for
 * vibidd's replay source and configuration, and for the Python package (through its
 * binding; python/vibid/_captures.py), so that a format is added in one place.
 *
 * Formats: CSV (a header of names; vibidd's raw recordings are CSV), candump -l logs
 * (can-utils; decoded with a DBC), ASAM MDF4 and NI TDMS (read by the Python package only;
 * vibidd refuses them naming `vibid convert`).
 *
 * Recognition (vibid_capture_format_of_file): the content first - "MDF     " at offset 0
 * (MDF4 and MDF3 identification block), "TDSm" (TDMS lead-in), a first line that is not a
 * '#' comment starting with "(seconds.micro)" (candump -l), or a line of text holding a
 * comma (CSV) -
 * then the extension when the content says nothing (an empty or unreadable file).
 * Thread-safe, no allocation; the table is static. */
#ifndef VIBID_DRIVERS_CAPTURE_FORMAT_H
#define VIBID_DRIVERS_CAPTURE_FORMAT_H

#include <stdbool.h>
#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef enum vibid_capture_format {
    VIBID_CAPTURE_UNKNOWN = 0,
    VIBID_CAPTURE_CANDUMP = 1, /* the same values as vibid_replay_format's (source_replay.h) */
    VIBID_CAPTURE_CSV = 2,
    VIBID_CAPTURE_MDF = 3,
    VIBID_CAPTURE_TDMS = 4
} vibid_capture_format;

typedef struct vibid_capture_format_info {
    vibid_capture_format format;
    const char *name;       /* "csv", "candump", "mdf", "tdms": the name configurations use */
    const char *aliases;    /* other accepted names, space-separated ("mf4 mdf4"), or "" */
    const char *extensions; /* lower-case file-name extensions with the dot, space-separated */
    const char *title;      /* for messages: "ASAM MDF4" */
    bool vibidd_replays;    /* vibidd's replay source reads it (else: Python only) */
    bool needs_dbc;         /* decoding needs a DBC (candump) */
} vibid_capture_format_info;

/* The table: *n entries (the known formats, in the enum's order, UNKNOWN excluded). */
const vibid_capture_format_info *vibid_capture_formats(size_t *n);

/* The entry of a format; NULL for UNKNOWN or a value outside the enum. */
const vibid_capture_format_info *vibid_capture_format_info_of(vibid_capture_format f);

/* A name or alias, any case ("CSV", "mf4"); UNKNOWN when none matches or name is NULL. */
vibid_capture_format vibid_capture_format_by_name(const char *name);

/* By the file name's extension alone, any case; UNKNOWN for another or no extension. */
vibid_capture_format vibid_capture_format_by_extension(const char *path);

/* By content: the first len bytes of a file (512 are enough); UNKNOWN when they decide
 * nothing (empty, only comments, binary of another kind). */
vibid_capture_format vibid_capture_format_sniff(const unsigned char *head, size_t len);

/* A file's format: its content (sniff of the first 512 bytes), else its extension, else
 * UNKNOWN (a file that cannot be opened is judged by its extension). */
vibid_capture_format vibid_capture_format_of_file(const char *path);

/* "csv, candump, mdf, tdms" style lists for messages: the names (all formats, or only those
 * vibidd replays) and their extensions, as "name (.ext .ext)" joined by ", ". Writes at most
 * cap bytes (NUL-terminated); returns buf. */
char *vibid_capture_format_list(char *buf, size_t cap, bool vibidd_only);

#ifdef __cplusplus
}
#endif

#endif
