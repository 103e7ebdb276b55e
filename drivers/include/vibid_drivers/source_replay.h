/* vibid_drivers/source_replay.h: the replay source: a capture file read back as if it
 * came from the bus, through the same decoding as the live sources.
 *
 * - candump .log (candump.h): frames go through the DBC and the CAN sample assembler
 *   (can_assembler.h) exactly as live SocketCAN frames do; DROPCOUNT lines become
 *   DROPPED faults; bad lines become BAD_LINE faults with file:line.
 * - CSV with a header row (csv_capture.h): every channel of the channel map names a
 *   `column`; the optional `time_column` gives the sample time in seconds. Each data
 *   row is one sample k = 0, 1, ...; a bad row is a BAD_LINE fault plus a one-sample
 *   GAP (the row is not used). With a time column and sample_period_s > 0, a time step
 *   of more than 1.5 periods gives a GAP of round(dt/h) - 1 samples, and time that does
 *   not increase is a BAD_LINE fault (row not used).
 * - A file whose last line has no newline was cut while being written: that line is a
 *   BAD_LINE fault "truncated capture" with file:line and is never turned into a value,
 *   even if it happens to parse.
 *
 * - Clock steps: in a candump log, a frame whose timestamp is earlier than the previous
 *   frame's, or later by more than max(VIBID_REPLAY_MAX_TIME_STEP_S, 1000 periods), is a
 *   CLOCK fault with file:line; the frame is used (the counter numbers samples) and the
 *   log's times from it on are shifted to continue at the previous frame's time.
 *
 * Pace: as fast as possible, or at the recorded pace (times speed): sample k is
 * released at start + (t_k - t_0) / speed on CLOCK_MONOTONIC, slept to with
 * clock_nanosleep(TIMER_ABSTIME), so pacing errors do not accumulate. A time step longer
 * than max(VIBID_REPLAY_MAX_TIME_STEP_S, 1000 periods) between two samples (a CSV
 * capture's pause, reported as a GAP) is not waited for.
 */
#ifndef VIBID_DRIVERS_SOURCE_REPLAY_H
#define VIBID_DRIVERS_SOURCE_REPLAY_H

#include <stdbool.h>

#include <vibid_drivers/channel_map.h>
#include <vibid_drivers/dbc.h>
#include <vibid_drivers/source.h>

#ifdef __cplusplus
extern "C" {
#endif

/* The longest time step between frames or samples a replay believes as elapsed time (at
 * least 1000 sample periods): a logger paused longer than this is replayed without the
 * wait, and a candump clock stepping further is a CLOCK fault (see above). */
#define VIBID_REPLAY_MAX_TIME_STEP_S 10.0

typedef enum vibid_replay_format {
    VIBID_REPLAY_AUTO = 0,   /* the file's format (capture_format.h: content, then extension);
                                one that says nothing is read as candump */
    VIBID_REPLAY_CANDUMP = 1,
    VIBID_REPLAY_CSV = 2
} vibid_replay_format;

/* The format a replay of `path` reads: f itself unless AUTO, else the file's format
 * (vibid_capture_format_of_file). A capture in a format the replay does not read (MDF4,
 * TDMS) gives VIBID_REPLAY_AUTO and err (cap bytes) naming the file, its format, the
 * formats vibidd replays and `vibid convert`. */
vibid_replay_format vibid_replay_format_resolve(vibid_replay_format f, const char *path, char *err, size_t cap);

typedef struct vibid_source_replay_config {
    const char *path;            /* capture file (copied) */
    vibid_replay_format format;
    const vibid_dbc *dbc;        /* candump only; must outlive the source */
    vibid_chanmap chanmap;       /* candump: signal channels (+ counter/trigger);
                                    CSV: column channels (+ time_column) */
    bool paced;                  /* false: as fast as possible */
    double speed;                /* paced: 1.0 = recorded pace, 2.0 = twice as fast; > 0 */
    double sample_period_s;      /* CSV: h; required without time_column (t_k = k h);
                                    with it optional (gap detection); candump: the
                                    counter plausibility check (can_assembler.h);
                                    0 = unknown */
} vibid_source_replay_config;

extern const vibid_source_ops vibid_source_replay_ops;

#ifdef __cplusplus
}
#endif
#endif
