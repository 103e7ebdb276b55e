/* Replay source: candump .log (DBC + assembler) and CSV captures; see source_replay.h. */
#include <vibid_drivers/source_replay.h>

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>
#include <unistd.h>

#include <vibid_drivers/can_assembler.h>
#include <vibid_drivers/candump.h>
#include <vibid_drivers/capture_format.h>
#include <vibid_drivers/csv_capture.h>

#include "rec_queue.h"
#include "source_util.h"

vibid_replay_format vibid_replay_format_resolve(vibid_replay_format f, const char *path, char *err, size_t cap)
{
    if (f == VIBID_REPLAY_CSV || f == VIBID_REPLAY_CANDUMP) return f;
    const vibid_capture_format c = vibid_capture_format_of_file(path);
    if (c == VIBID_CAPTURE_CSV) return VIBID_REPLAY_CSV;
    const vibid_capture_format_info *info = vibid_capture_format_info_of(c);
    if (info && !info->vibidd_replays) {
        char list[256];
        snprintf(err, cap,
                 "%s: an %s capture, which vibidd does not replay (it replays %s): convert it to CSV first, "
                 "e.g. `vibid convert STAND %s OUT.csv` (docs/python.md)",
                 path, info->title, vibid_capture_format_list(list, sizeof list, true), path);
        return VIBID_REPLAY_AUTO;
    }
    return VIBID_REPLAY_CANDUMP; /* a candump log, or content that says nothing: the candump reader judges */
}

#define QUEUE_CAP 64
#define PRODUCE_RESERVE 24 /* records one input line can produce, with margin */

typedef struct replay {
    vibid_source_replay_config cfg;
    char path[4096];
    const char *base;              /* file name without directories, for record texts */
    bool csv;
    unsigned long truncated_line;  /* line without newline at the end of the file, or 0 */
    /* candump */
    vibid_candump_reader *cd;
    vibid_can_assembler *as;
    bool have_frame_t;
    int64_t last_frame_t;          /* re-based time of the previous frame, ns */
    int64_t clock_offset;          /* added to the log's times after clock steps, ns */
    /* CSV */
    vibid_csv_reader *cr;
    int col[VIBID_DRV_MAX_CHANNELS];
    int tcol;
    double row[VIBID_CSV_MAX_COLUMNS];
    uint64_t k;
    bool have_t;
    int64_t last_t;
    uint64_t csv_bad_extra;        /* truncated/non-increasing rows the CSV reader accepted */
    /* output */
    rec_queue q;
    bool eof;
    vibid_drv_status fatal;
    char fatal_text[VIBID_DRV_ERROR_LEN];
    bool pace_started;
    int64_t t0_rec, t0_mono;
    int64_t pace_last_t;           /* time of the last sample handed out paced, ns */
    vibid_source_stats st;
    int64_t last_sample_t;
} replay;

/* Line number of an unterminated last line (file cut while written), 0 if none. */
static vibid_drv_status find_truncation(replay *r, vibid_drv_error *err)
{
    int fd = open(r->path, O_RDONLY | O_CLOEXEC);
    if (fd < 0)
        return vibid_drv_fail(err, VIBID_DRV_E_IO, "%s: cannot open: %s", r->path, strerror(errno));
    struct stat sb;
    char last = '\n';
    vibid_drv_status st = VIBID_DRV_OK;
    if (fstat(fd, &sb) != 0 || (sb.st_size > 0 && pread(fd, &last, 1, sb.st_size - 1) != 1)) {
        st = vibid_drv_fail(err, VIBID_DRV_E_IO, "%s: cannot read: %s", r->path, strerror(errno));
    } else if (last != '\n') {
        unsigned long lines = 0;
        char buf[65536];
        ssize_t got;
        while ((got = read(fd, buf, sizeof buf)) > 0)
            for (const char *p = buf; (p = memchr(p, '\n', (size_t)(buf + got - p))) != NULL; p++)
                lines++;
        if (got < 0)
            st = vibid_drv_fail(err, VIBID_DRV_E_IO, "%s: read error: %s", r->path, strerror(errno));
        r->truncated_line = lines + 1;
    }
    close(fd);
    return st;
}

/* The header's column names, quoted, for a message: "'t', 'x1', 'x2'" (cut with "..." to fit) */
static const char *header_names(const vibid_csv_reader *cr, char *buf, size_t cap)
{
    size_t off = 0;
    buf[0] = '\0';
    for (size_t i = 0; i < vibid_csv_column_count(cr); i++) {
        int n = snprintf(buf + off, cap - off, "%s'%s'", i ? ", " : "", vibid_csv_column_name(cr, i));
        if (n < 0 || (size_t)n >= cap - off) {
            snprintf(buf + (off < cap - 6 ? off : cap - 6), 6, ", ...");
            break;
        }
        off += (size_t)n;
    }
    return buf;
}

static vibid_drv_status open_csv(replay *r, vibid_source *src, vibid_drv_error *err)
{
    char names[200];
    r->cr = vibid_csv_open(r->path, err);
    if (!r->cr)
        return err ? err->status : VIBID_DRV_E_IO;
    const vibid_chanmap *m = &src->chanmap;
    for (size_t c = 0; c < m->n; c++) {
        const vibid_channel *ch = &m->ch[c];
        if (ch->source != VIBID_CHAN_COLUMN)
            return vibid_drv_fail(err, VIBID_DRV_E_ARG,
                                  "channel '%s' (line %u): a CSV replay needs column = \"...\"", ch->name, ch->line);
        r->col[c] = vibid_csv_find_column(r->cr, ch->ref);
        if (r->col[c] < 0)
            return vibid_drv_fail(err, VIBID_DRV_E_NOT_FOUND,
                                  "channel '%s' (line %u): column '%s' is not in the header of %s (its columns: %s)",
                                  ch->name, ch->line, ch->ref, r->path, header_names(r->cr, names, sizeof names));
    }
    r->tcol = -1;
    if (m->time_column[0]) {
        r->tcol = vibid_csv_find_column(r->cr, m->time_column);
        if (r->tcol < 0)
            return vibid_drv_fail(err, VIBID_DRV_E_NOT_FOUND,
                                  "time_column '%s' is not in the header of %s (its columns: %s)", m->time_column,
                                  r->path, header_names(r->cr, names, sizeof names));
    } else if (!(r->cfg.sample_period_s > 0)) {
        return vibid_drv_fail(err, VIBID_DRV_E_ARG,
                              "%s: no time_column in the channel map: the sample period must be given", r->path);
    }
    return VIBID_DRV_OK;
}

static vibid_drv_status replay_open(vibid_source *src, const void *config, vibid_drv_error *err)
{
    const vibid_source_replay_config *cfg = config;
    replay *r = calloc(1, sizeof *r);
    if (!r)
        return vibid_drv_fail(err, VIBID_DRV_E_NOMEM, "replay source: out of memory");
    src->impl = r;
    if (!cfg->path || !cfg->path[0])
        return vibid_drv_fail(err, VIBID_DRV_E_ARG, "replay source: no capture file given");
    if (strlen(cfg->path) >= sizeof r->path)
        return vibid_drv_fail(err, VIBID_DRV_E_ARG, "replay source: path too long");
    if (cfg->chanmap.n == 0)
        return vibid_drv_fail(err, VIBID_DRV_E_ARG, "replay source %s: empty channel map", cfg->path);
    if (cfg->paced && !(cfg->speed > 0 && isfinite(cfg->speed)))
        return vibid_drv_fail(err, VIBID_DRV_E_ARG, "replay source %s: speed %g must be > 0", cfg->path, cfg->speed);
    if (!(cfg->sample_period_s >= 0 && isfinite(cfg->sample_period_s)))
        return vibid_drv_fail(err, VIBID_DRV_E_ARG, "replay source %s: sample period %g invalid", cfg->path,
                              cfg->sample_period_s);
    r->cfg = *cfg;
    snprintf(r->path, sizeof r->path, "%s", cfg->path);
    r->cfg.path = r->path;
    const char *slash = strrchr(r->path, '/');
    r->base = slash ? slash + 1 : r->path;
    src->chanmap = cfg->chanmap;
    char why[512];
    const vibid_replay_format format = vibid_replay_format_resolve(cfg->format, r->path, why, sizeof why);
    if (format == VIBID_REPLAY_AUTO)
        return vibid_drv_fail(err, VIBID_DRV_E_UNSUPPORTED, "replay source: %s", why);
    r->csv = format == VIBID_REPLAY_CSV;
    if (!rec_queue_init(&r->q, QUEUE_CAP))
        return vibid_drv_fail(err, VIBID_DRV_E_NOMEM, "replay source: out of memory");
    vibid_drv_status st = find_truncation(r, err);
    if (st != VIBID_DRV_OK)
        return st;
    if (r->csv)
        return open_csv(r, src, err);
    if (!cfg->dbc)
        return vibid_drv_fail(err, VIBID_DRV_E_ARG, "replay of candump log %s needs a DBC", r->path);
    r->as = vibid_can_assembler_create(cfg->dbc, &src->chanmap, err);
    if (!r->as)
        return err ? err->status : VIBID_DRV_E_ARG;
    vibid_can_assembler_set_timing(r->as, cfg->sample_period_s, 0); /* validated above */
    r->cd = vibid_candump_reader_open(r->path, err);
    if (!r->cd)
        return err ? err->status : VIBID_DRV_E_IO;
    return VIBID_DRV_OK;
}

static void set_fatal(replay *r, vibid_drv_status st, const char *text)
{
    r->fatal = st;
    snprintf(r->fatal_text, sizeof r->fatal_text, "%s", text);
    r->eof = true;
}

/* Moves the assembler's records to the queue; faults get "file:line: " in front and gaps
 * name the line at which they were detected. */
static void drain_assembler(replay *r, unsigned long line)
{
    /* Popped straight into the queue's slot: one record copy less per sample. */
    while (rec_queue_space(&r->q) > 0 && vibid_can_assembler_pending(r->as) > 0) {
        vibid_record *rec = rec_queue_push(&r->q, VIBID_REC_SAMPLE); /* space checked above */
        vibid_can_assembler_pop(r->as, rec);
        if (rec->kind == VIBID_REC_SAMPLE || !line)
            continue;
        char tmp[sizeof rec->text];
        memcpy(tmp, rec->text, sizeof tmp);
        if (rec->kind == VIBID_REC_FAULT)
            rec_text(rec, "%s:%lu: %s", r->base, line, tmp);
        else
            rec_text(rec, "%s (at %s:%lu)", tmp, r->base, line);
    }
}

/* A candump log's clock must move forward by plausible steps: a timestamp earlier than the
 * previous frame's, or later by more than max(VIBID_REPLAY_MAX_TIME_STEP_S, 1000 sample
 * periods), is a clock step of the logger (an NTP step, a reset, a corrupt field), not
 * elapsed time: a paced replay would wait for days, and a counter jump would look
 * plausible. The frame is used (its counter numbers the sample, so nothing is invented or
 * dropped); from it on the log's times are shifted so that it lies at the previous
 * frame's time, and a fault says so. */
static double max_time_step(const replay *r)
{
    double h = r->cfg.sample_period_s;
    return 1000.0 * h > VIBID_REPLAY_MAX_TIME_STEP_S ? 1000.0 * h : VIBID_REPLAY_MAX_TIME_STEP_S;
}

static void rebase_frame_time(replay *r, vibid_candump_entry *e)
{
    int64_t t = e->frame.t_ns + r->clock_offset;
    if (r->have_frame_t) {
        double max_step = max_time_step(r);
        double step = (double)(t - r->last_frame_t) * 1e-9;
        if (step < 0 || step > max_step) {
            int64_t to = r->last_frame_t;
            r->clock_offset += to - t;
            rec_queue_fault(&r->q, VIBID_FAULT_CLOCK, 0, 0,
                            "%.100s:%lu: time steps %+.6g s from the previous frame (allowed 0 .. %.6g s): a clock "
                            "step, the replay's times are shifted by %+.6g s from here",
                            r->base, e->line, step, max_step, (double)r->clock_offset * 1e-9);
            t = to;
        }
    }
    r->have_frame_t = true;
    r->last_frame_t = t;
    e->frame.t_ns = t;
}

static void produce_candump(replay *r)
{
    vibid_candump_entry e;
    vibid_drv_status st = vibid_candump_reader_next(r->cd, &e);
    if (st == VIBID_DRV_E_EOF) {
        vibid_can_assembler_finish(r->as);
        drain_assembler(r, 0);
        r->eof = true;
        return;
    }
    if (st != VIBID_DRV_OK) {
        set_fatal(r, st, e.text);
        return;
    }
    bool cut = r->truncated_line && e.line == r->truncated_line;
    switch (e.kind) {
    case VIBID_CANDUMP_FRAME:
        if (cut) {
            r->st.bad_lines++;
            rec_queue_fault(&r->q, VIBID_FAULT_BAD_LINE, 0, 0,
                            "%.100s:%lu: last line has no newline: truncated capture, frame not used", r->base,
                            e.line);
            return;
        }
        rebase_frame_time(r, &e);
        vibid_can_assembler_push(r->as, &e.frame);
        break;
    case VIBID_CANDUMP_DROPCOUNT: {
        char where[64];
        snprintf(where, sizeof where, "DROPCOUNT at %.30s:%lu", r->base, e.line);
        vibid_can_assembler_note_drops(r->as, e.dropped, where);
        break;
    }
    case VIBID_CANDUMP_BAD_LINE:
        rec_queue_fault(&r->q, VIBID_FAULT_BAD_LINE, 0, 0, "%.130s%s", e.text, cut ? " (truncated capture)" : "");
        return;
    case VIBID_CANDUMP_EMPTY:
        return;
    }
    drain_assembler(r, e.line);
}

static void csv_row_missing(replay *r)
{
    /* With a time column and a known period the next good row's time step makes the
     * gap; otherwise the row itself was sample k. */
    if (!(r->tcol >= 0 && r->cfg.sample_period_s > 0)) {
        rec_queue_gap(&r->q, r->k, 1, "row not usable (see the fault before)");
        r->k++;
    }
}

static void produce_csv(replay *r)
{
    vibid_drv_error err = {0};
    unsigned long line = 0;
    vibid_drv_status st = vibid_csv_next(r->cr, r->row, &line, &err);
    if (st == VIBID_DRV_E_EOF) {
        r->eof = true;
        return;
    }
    bool cut = r->truncated_line && line == r->truncated_line;
    if (st == VIBID_DRV_E_SYNTAX) {
        rec_queue_fault(&r->q, VIBID_FAULT_BAD_LINE, r->k, 0, "%.130s%s", err.text, cut ? " (truncated capture)" : "");
        csv_row_missing(r);
        return;
    }
    if (st != VIBID_DRV_OK) {
        set_fatal(r, st, err.text);
        return;
    }
    if (cut) {
        r->csv_bad_extra++;
        rec_queue_fault(&r->q, VIBID_FAULT_BAD_LINE, r->k, 0,
                        "%.100s:%lu: last line has no newline: truncated capture, row not used", r->base, line);
        csv_row_missing(r);
        return;
    }
    const double h = r->cfg.sample_period_s;
    int64_t t;
    if (r->tcol >= 0) {
        double ts = r->row[r->tcol];
        if (!(fabs(ts) < 9.2e9)) {
            r->csv_bad_extra++;
            rec_queue_fault(&r->q, VIBID_FAULT_BAD_LINE, r->k, 0, "%.100s:%lu: time %g s out of range", r->base,
                            line, ts);
            csv_row_missing(r);
            return;
        }
        t = llround(ts * 1e9);
        if (r->have_t && t <= r->last_t) {
            r->csv_bad_extra++;
            rec_queue_fault(&r->q, VIBID_FAULT_BAD_LINE, r->k, 0,
                            "%.90s:%lu: time %.9g s does not increase (previous %.9g s): row not used", r->base,
                            line, ts, (double)r->last_t * 1e-9);
            csv_row_missing(r);
            return;
        }
        if (r->have_t && h > 0) {
            double dt = (double)(t - r->last_t) * 1e-9;
            if (dt > 1.5 * h) {
                uint64_t miss = (uint64_t)llround(dt / h) - 1;
                rec_queue_gap(&r->q, r->k, miss, "%.100s:%lu: time step %.6g s = %.1f periods", r->base, line,
                              dt, dt / h);
                r->k += miss;
            }
        }
        r->have_t = true;
        r->last_t = t;
    } else {
        t = llround((double)r->k * h * 1e9);
    }
    vibid_record *s = rec_queue_push(&r->q, VIBID_REC_SAMPLE);
    s->index = r->k++;
    s->t_ns = t;
    s->n_values = (uint32_t)r->cfg.chanmap.n;
    for (size_t c = 0; c < r->cfg.chanmap.n; c++)
        s->values[c] = r->row[r->col[c]];
}

static vibid_drv_status replay_read(vibid_source *src, vibid_record *recs, size_t cap, size_t *n,
                                    int timeout_ms, vibid_drv_error *err)
{
    replay *r = src->impl;
    int64_t limit = r->cfg.paced ? wait_limit(timeout_ms) : 0;
    size_t k = 0;
    while (k < cap) {
        const vibid_record *head = rec_queue_peek(&r->q);
        if (!head) {
            if (r->eof)
                break;
            while (!r->eof && rec_queue_space(&r->q) >= PRODUCE_RESERVE && r->q.len < 8) {
                if (r->csv)
                    produce_csv(r);
                else
                    produce_candump(r);
            }
            continue;
        }
        if (r->cfg.paced && head->kind == VIBID_REC_SAMPLE) {
            if (!r->pace_started) {
                r->pace_started = true;
                r->t0_rec = head->t_ns;
                r->t0_mono = mono_ns();
            } else if ((double)(head->t_ns - r->pace_last_t) * 1e-9 > max_time_step(r)) {
                /* a pause in a CSV capture (its gap is reported when produced) is not
                 * waited for: the sample is due right after the previous one */
                r->t0_rec += head->t_ns - r->pace_last_t;
            }
            r->pace_last_t = head->t_ns;
            int64_t deadline = r->t0_mono + (int64_t)((double)(head->t_ns - r->t0_rec) / r->cfg.speed);
            if (deadline > mono_ns()) {
                if (k > 0)
                    break; /* hand out what is due now */
                if (deadline > limit) {
                    sleep_until_mono(limit);
                    break;
                }
                sleep_until_mono(deadline);
            }
        }
        vibid_record_copy(&recs[k], head);
        vibid_source_stats_count(&r->st, &recs[k], &r->last_sample_t);
        rec_queue_drop_head(&r->q);
        k++;
    }
    *n = k;
    if (k)
        return VIBID_DRV_OK;
    if (r->eof && !rec_queue_peek(&r->q)) {
        if (r->fatal != VIBID_DRV_OK)
            return vibid_drv_fail(err, r->fatal, "%s", r->fatal_text);
        return VIBID_DRV_E_EOF;
    }
    return VIBID_DRV_E_AGAIN;
}

static void replay_close(vibid_source *src)
{
    replay *r = src->impl;
    if (!r)
        return;
    vibid_candump_reader_close(r->cd);
    vibid_can_assembler_destroy(r->as);
    vibid_csv_close(r->cr);
    rec_queue_free(&r->q);
    free(r);
    src->impl = NULL;
}

static void replay_stats(const vibid_source *src, vibid_source_stats *st)
{
    const replay *r = src->impl;
    *st = r->st;
    if (r->cd) {
        vibid_candump_stats cs;
        vibid_candump_reader_stats(r->cd, &cs);
        st->lines = cs.lines;
        st->bad_lines += cs.bad_lines;
    }
    if (r->as) {
        vibid_can_assembler_stats as;
        vibid_can_assembler_stats_get(r->as, &as);
        st->frames = as.frames;
        st->error_frames = as.error_frames;
        st->bus_off = as.bus_off;
        st->ctrl_overflow = as.ctrl_overflow;
        st->restarts = as.restarts;
        st->dropped = as.dropped;
        st->unknown_ids = as.unknown_ids;
        st->short_frames = as.short_frames;
        st->nonfinite = as.nonfinite;
        st->duplicates = as.duplicates;
        st->late = as.late;
    }
    if (r->cr) {
        vibid_csv_stats cs;
        vibid_csv_stats_get(r->cr, &cs);
        st->lines = cs.lines;
        st->bad_lines += cs.bad_rows + r->csv_bad_extra;
    }
}

const vibid_source_ops vibid_source_replay_ops = {"replay", replay_open, replay_read, replay_close,
                                                  replay_stats};
