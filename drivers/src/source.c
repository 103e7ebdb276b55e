/* Generic source handle: dispatch through the kind's const ops table. */
#include <vibid_drivers/source.h>

#include <math.h>
#include <stdlib.h>
#include <string.h>

vibid_source *vibid_source_open(const vibid_source_ops *ops, const void *config, vibid_drv_error *err)
{
    if (!ops || !ops->open || !ops->read || !ops->close || !ops->stats || !config) {
        vibid_drv_fail(err, VIBID_DRV_E_ARG, "vibid_source_open: ops table and config are required");
        return NULL;
    }
    vibid_source *s = calloc(1, sizeof *s);
    if (!s) {
        vibid_drv_fail(err, VIBID_DRV_E_NOMEM, "%s source: out of memory", ops->kind);
        return NULL;
    }
    s->ops = ops;
    if (ops->open(s, config, err) != VIBID_DRV_OK) {
        ops->close(s);
        free(s);
        return NULL;
    }
    return s;
}

vibid_drv_status vibid_source_read(vibid_source *src, vibid_record *recs, size_t cap, size_t *n,
                                   int timeout_ms, vibid_drv_error *err)
{
    if (n)
        *n = 0;
    if (!src || !recs || cap == 0 || !n)
        return vibid_drv_fail(err, VIBID_DRV_E_ARG, "vibid_source_read: source, records and cap >= 1 needed");
    return src->ops->read(src, recs, cap, n, timeout_ms, err);
}

void vibid_source_stats_get(const vibid_source *src, vibid_source_stats *st)
{
    if (!st)
        return;
    memset(st, 0, sizeof *st);
    if (src)
        src->ops->stats(src, st);
    vibid_jitter_finish(&st->jitter);
}

const vibid_chanmap *vibid_source_channels(const vibid_source *src) { return src ? &src->chanmap : NULL; }

const char *vibid_source_kind(const vibid_source *src) { return src ? src->ops->kind : "none"; }

void vibid_source_close(vibid_source *src)
{
    if (!src)
        return;
    src->ops->close(src);
    free(src);
}

void vibid_jitter_finish(vibid_jitter_stats *j) { j->std_s = j->n > 1 ? sqrt(j->m2_s2 / (double)(j->n - 1)) : 0.0; }

const char *vibid_fault_name(vibid_fault_code c)
{
    static const char *const n[] = {"none",      "bad_line", "unknown_id", "short_frame", "nonfinite",
                                    "duplicate", "late",     "bus_error",  "dropped",     "poll",
                                    "link",      "corrupt",  "clock"};
    /* one name per code: a code added to the enum without a name here fails to compile */
    _Static_assert(sizeof n / sizeof n[0] == VIBID_FAULT_LAST + 1, "a name for every vibid_fault_code");
    return (unsigned)c < sizeof n / sizeof n[0] ? n[c] : "fault";
}

void vibid_source_stats_count(vibid_source_stats *st, const vibid_record *rec, int64_t *last_t_ns)
{
    switch (rec->kind) {
    case VIBID_REC_SAMPLE: {
        st->samples++;
        if (st->samples > 1)
            vibid_jitter_add(&st->jitter, (double)(rec->t_ns - *last_t_ns) * 1e-9);
        *last_t_ns = rec->t_ns;
        break;
    }
    case VIBID_REC_GAP:
        st->gaps++;
        st->missing_samples += rec->count;
        break;
    case VIBID_REC_FAULT:
        st->faults++;
        break;
    }
}

/* ---- test double ---- */
typedef struct double_impl {
    vibid_source_double_config cfg;
    vibid_record *recs;
    size_t pos, reads;
    vibid_source_stats st;
    int64_t last_t;
} double_impl;

static vibid_drv_status double_open(vibid_source *src, const void *config, vibid_drv_error *err)
{
    const vibid_source_double_config *cfg = config;
    if (cfg->n_records && !cfg->records)
        return vibid_drv_fail(err, VIBID_DRV_E_ARG, "double source: n_records > 0 but records is NULL");
    double_impl *d = calloc(1, sizeof *d);
    if (!d)
        return vibid_drv_fail(err, VIBID_DRV_E_NOMEM, "double source: out of memory");
    src->impl = d;
    d->cfg = *cfg;
    src->chanmap = cfg->chanmap;
    if (cfg->n_records) {
        d->recs = malloc(cfg->n_records * sizeof *d->recs);
        if (!d->recs)
            return vibid_drv_fail(err, VIBID_DRV_E_NOMEM, "double source: out of memory");
        memcpy(d->recs, cfg->records, cfg->n_records * sizeof *d->recs);
    }
    d->cfg.records = d->recs;
    return VIBID_DRV_OK;
}

static vibid_drv_status double_read(vibid_source *src, vibid_record *recs, size_t cap, size_t *n,
                                    int timeout_ms, vibid_drv_error *err)
{
    (void)timeout_ms;
    double_impl *d = src->impl;
    d->reads++;
    if (d->cfg.fail_after_reads && d->reads == d->cfg.fail_after_reads)
        return vibid_drv_fail(err, d->cfg.fail_status ? d->cfg.fail_status : VIBID_DRV_E_IO,
                              "double source: scripted failure on read #%zu", d->reads);
    size_t lim = d->cfg.max_batch && d->cfg.max_batch < cap ? d->cfg.max_batch : cap;
    size_t k = 0;
    while (k < lim && d->pos < d->cfg.n_records) {
        recs[k] = d->recs[d->pos++];
        vibid_source_stats_count(&d->st, &recs[k], &d->last_t);
        k++;
    }
    *n = k;
    if (k)
        return VIBID_DRV_OK;
    return d->cfg.endless ? VIBID_DRV_E_AGAIN : VIBID_DRV_E_EOF;
}

static void double_close(vibid_source *src)
{
    double_impl *d = src->impl;
    if (d) {
        free(d->recs);
        free(d);
    }
    src->impl = NULL;
}

static void double_stats(const vibid_source *src, vibid_source_stats *st)
{
    const double_impl *d = src->impl;
    *st = d->st;
}

const vibid_source_ops vibid_source_double_ops = {"double", double_open, double_read, double_close,
                                                  double_stats};
