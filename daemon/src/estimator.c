/* estimator.c: see estimator.h. */
#include "estimator.h"
#include "log.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

int64_t vd_ns_to_us(int64_t t_ns)
{
    int64_t q = t_ns / 1000, r = t_ns % 1000;
    if (r < 0) {
        q -= 1;
        r += 1000;
    }
    return r >= 500 ? q + 1 : q;
}

/* The outlier test over the model channels (estimator.outlier_threshold or
 * oma.outlier_threshold). 0, or -1 with err. */
static int init_outlier_test(vd_est *e, const char *setting, char *err, size_t cap)
{
    if (!(e->cfg->outlier_threshold > 0.0))
        return 0;
    vibid_outlier_config oc;
    vibid_outlier_config_init(&oc, e->nch);
    oc.threshold = e->cfg->outlier_threshold;
    e->outl = vibid_outlier_create(&oc);
    if (!e->outl) {
        snprintf(err, cap, "%s: %s", setting, vibid_last_error());
        return -1;
    }
    /* the most the test holds at once (vibid/outlier.h) */
    e->held_cap = (oc.warmup > VIBID_OUTLIER_LOOKAHEAD + 1 ? oc.warmup : VIBID_OUTLIER_LOOKAHEAD + 1) + 1;
    e->held = calloc(e->held_cap, sizeof *e->held);
    e->held_tag = calloc(e->held_cap, sizeof *e->held_tag);
    if (!e->held || !e->held_tag) {
        snprintf(err, cap, "estimator: out of memory");
        return -1;
    }
    return 0;
}

/* Output-only (oma.on): no estimator; the samples (outliers taken out) go to the mode
 * tracker (oma_track.h), which makes the rows. */
static int init_output_only(vd_est *e, char *err, size_t cap)
{
    const vd_config *cfg = e->cfg;
    e->nch = cfg->n_channels;
    e->p = cfg->n_params;
    const vd_oma_config *a = &cfg->oma;
    int n = snprintf(e->choices, sizeof e->choices,
                     "output-only: SSI-cov (vibid/oma.h) of %zu response channels over the last %g s every %g s of "
                     "sample time, in blocks of %g s, %u block rows\n"
                     "tracked modes: %zu (%s); a mode continues when within %g %% in frequency and MAC >= %g\n",
                     cfg->n_channels, a->window_s, a->every_s, a->block_s, a->block_rows, a->n_modes,
                     a->nominal_hz[0] > 0.0 ? "nearest to the expected frequencies"
                                            : "the lowest of the first identification that finds as many",
                     100.0 * a->match_freq, a->match_mac);
    e->choices_len = n > 0 ? (size_t)n : 0;
    if (init_outlier_test(e, "oma.outlier_threshold", err, cap)) {
        vd_est_free(e);
        return -1;
    }
    snprintf(e->twin_why, sizeof e->twin_why, "output-only: rows come from the mode tracker");
    return 0;
}

int vd_est_init(vd_est *e, const vd_config *cfg, char *err, size_t cap)
{
    memset(e, 0, sizeof *e);
    e->cfg = cfg;
    if (cfg->oma.on)
        return init_output_only(e, err, cap);
    e->model = vibid_stand_model(cfg->stand);
    vibid_ident_config ic;
    vibid_ident_config_init(&ic, 1.0 / cfg->sample_rate);
    ic.estimator = cfg->method;
    ic.prefilter_hz = cfg->prefilter_hz;
    ic.iv_lag = cfg->iv_lag;
    ic.forgetting = cfg->forgetting;
    ic.rls_alpha = cfg->rls_alpha;
    ic.difference_order = cfg->difference_order;
    e->ident = vibid_ident_create(e->model, &ic);
    if (!e->ident) {
        snprintf(err, cap, "%s: estimator: %s", cfg->stand_file[0] ? cfg->stand_file : cfg->path, vibid_last_error());
        return -1;
    }
    /* What the automatic estimator chose and why: for --check, the log and the tracks
     * file's header. */
    vibid_ident_get_config(e->ident, &e->resolved);
    vibid_ident_describe(e->ident, e->choices, sizeof e->choices, &e->choices_len);
    vibid_ident_dims(e->ident, &e->nch, &e->p);
    if (cfg->has_start && vibid_ident_set_prior(e->ident, cfg->start_theta, NULL) != VIBID_OK) {
        snprintf(err, cap, "%s: estimator.start_values: %s", cfg->path, vibid_last_error());
        vibid_ident_destroy(e->ident);
        e->ident = NULL;
        return -1;
    }
    e->nmodes = cfg->n_modes;
    /* The row's checks (vibid/report.h); its plausibility reference (the stand's nominal
     * modes) is made here: it allocates, rows do not add to that. */
    e->report = vibid_report_create(e->model, 1.0 / cfg->sample_rate);
    if (!e->report) {
        snprintf(err, cap, "estimator: %s", vibid_last_error());
        vd_est_free(e);
        return -1;
    }
    e->pref = *vibid_report_reference(e->report);
    if (init_outlier_test(e, "estimator.outlier_threshold", err, cap)) {
        vd_est_free(e);
        return -1;
    }
    /* A twin takes each row's estimator state at its sample, so that the row's estimate
     * (30-100 us) is computed while no sample waits (estimator.h). LS and the state-space
     * estimators (also the one the automatic choice makes for a stand not fully measured)
     * have none: their rows are computed at their sample, as they were before. */
    e->twin = vibid_ident_twin_create(e->ident);
    if (!e->twin)
        snprintf(e->twin_why, sizeof e->twin_why, "%s", vibid_last_error());
    return 0;
}

int vd_next_line(const char **text, int *len)
{
    const char *l = *text;
    if (!l || !*l)
        return 0;
    const char *nl = strchr(l, '\n');
    *len = nl ? (int)(nl - l) : (int)strlen(l);
    *text = l + *len + (nl ? 1 : 0);
    return 1;
}

void vd_est_print_choices(const vd_est *e, FILE *out, const char *prefix)
{
    const char *rest = e->choices, *line = rest;
    int len;
    while (vd_next_line(&rest, &len)) {
        fprintf(out, "%s%.*s\n", prefix, len, line);
        line = rest;
    }
}

void vd_est_log_choices(const vd_est *e)
{
    const char *rest = e->choices, *line = rest;
    int len;
    while (vd_next_line(&rest, &len)) {
        vd_info("%.*s", len, line);
        line = rest;
    }
    if (!e->twin && e->ident)
        vd_info("track rows: estimated at their sample, later samples wait for them (%s)", e->twin_why);
}

void vd_est_free(vd_est *e)
{
    vibid_ident_destroy(e->twin);
    e->twin = NULL;
    vibid_ident_destroy(e->ident);
    e->ident = NULL;
    vibid_report_destroy(e->report);
    e->report = NULL;
    vibid_outlier_destroy(e->outl);
    e->outl = NULL;
    free(e->held);
    e->held = NULL;
    free(e->held_tag);
    e->held_tag = NULL;
}

void vd_flag_letters(unsigned flags, char out[VD_FLAG_LETTERS_MAX])
{
    static const struct {
        unsigned bit;
        char letter;
    } order[] = {{VD_FLAG_GAP, 'G'},        {VD_FLAG_OUTLIER, 'O'},     {VD_FLAG_NOEST, 'E'}, {VD_FLAG_IMPLAUSIBLE, 'P'},
                 {VD_FLAG_SE_INVALID, 'U'}, {VD_FLAG_NOT_EXCITED, 'I'}, {VD_FLAG_ALARM, 'A'},
                 {VD_FLAG_COVARIATE, 'C'},  {VD_FLAG_REFINED, 'W'}};
    int n = 0;
    for (size_t i = 0; i < sizeof order / sizeof order[0]; i++)
        if (flags & order[i].bit)
            out[n++] = order[i].letter;
    out[n] = '\0';
}

/* A record's values in the model's channels and the stand's units (a GAP: all NaN). */
static void model_values(const vd_est *e, const vibid_record *rec, double *out)
{
    for (size_t i = 0; i < e->nch; i++)
        out[i] = rec->kind == VIBID_REC_SAMPLE ? rec->values[e->cfg->model_to_chan[i]] * e->cfg->model_scale[i] : NAN;
}

/* The records the last feed or flush released have all been handed out: they leave the
 * queue (the held ones that were released; the fed record itself was never copied). */
static void drop_released(vd_est *e)
{
    size_t gone = e->rel_n < e->n_held ? e->rel_n : e->n_held;
    if (gone) {
        memmove(e->held, e->held + gone, (e->n_held - gone) * sizeof *e->held);
        memmove(e->held_tag, e->held_tag + gone, (e->n_held - gone) * sizeof *e->held_tag);
        e->n_held -= gone;
    }
    e->rel_n = e->rel_i = 0;
    e->cur = NULL;
}

void vd_est_feed(vd_est *e, const vibid_record *rec, int64_t tag)
{
    drop_released(e);
    e->cur = rec;
    e->cur_tag = tag;
    e->cur_first = e->n_held;
    if (!e->outl) {
        e->rel_n = 1;
        return;
    }
    double v[VIBID_DRV_MAX_CHANNELS];
    model_values(e, rec, v);
    size_t n = 0;
    (void)vibid_outlier_push(e->outl, v, &n); /* cannot fail: arguments checked at init */
    e->rel_n = n;
    if (n <= e->n_held) { /* the fed record waits: kept (the caller's copy does not live on) */
        vibid_record_copy(&e->held[e->n_held], rec);
        e->held_tag[e->n_held++] = tag;
    }
}

void vd_est_flush(vd_est *e)
{
    drop_released(e);
    e->cur_first = e->n_held;
    if (e->outl)
        (void)vibid_outlier_flush(e->outl, &e->rel_n);
}

const vibid_record *vd_est_next(vd_est *e, int64_t *tag)
{
    if (e->rel_i >= e->rel_n)
        return NULL;
    size_t i = e->rel_i++;
    e->rel_outliers = 0;
    if (e->outl)
        (void)vibid_outlier_released(e->outl, i, e->chan, e->rel_out, &e->rel_outliers);
    if (i < e->cur_first) {
        *tag = e->held_tag[i];
        return &e->held[i];
    }
    *tag = e->cur_tag;
    return e->cur;
}

static void restart_window(vd_est *e)
{
    if (!e->ident) /* output-only: the mode tracker hears of the gap from the daemon */
        return;
    double nanv[VIBID_DRV_MAX_CHANNELS];
    for (size_t i = 0; i < e->nch; i++)
        nanv[i] = NAN;
    (void)vibid_ident_push(e->ident, nanv); /* VIBID_E_NONFINITE by design: restarts the window */
}

static void note_gap(vd_est *e, uint64_t count)
{
    if (count == 0)
        return;
    e->gaps++;
    e->missing += count;
    e->gap_since_row += count;
    restart_window(e);
}

/* A sample had values taken out by the outlier test: counted, flagged O on the next row,
 * logged (the first 20, then every 1000th) with what was received. */
static void note_outlier(vd_est *e, const vibid_record *rec)
{
    e->outliers++;
    e->outlier_since_row++;
    if (e->outliers > 20 && e->outliers % 1000 != 0)
        return;
    char what[256];
    size_t off = 0;
    what[0] = '\0';
    for (size_t i = 0; i < e->nch && off < sizeof what; i++)
        if (e->rel_out[i]) {
            size_t src = e->cfg->model_to_chan[i];
            int n = snprintf(what + off, sizeof what - off, "%s%s = %.17g", off ? ", " : "",
                             e->cfg->chanmap.ch[src].name, rec->values[src]);
            off += n > 0 ? (size_t)n : 0;
        }
    vd_notice("outlier: sample %llu: %s taken out (a single-sample glitch; the estimator sees a gap; %llu so far)",
              (unsigned long long)(rec->index - e->first_index), what, (unsigned long long)e->outliers);
}

/* The pre-filter pilot (identify.h) ended since the last row: its choice goes to the
 * log (the tracks file's header was written at the start; it states the rule). */
static void note_new_choices(vd_est *e)
{
    size_t len = 0;
    if (!e->ident)
        return;
    if (vibid_ident_describe(e->ident, NULL, 0, &len) != VIBID_OK || len == e->choices_len)
        return;
    vibid_ident_get_config(e->ident, &e->resolved);
    vibid_ident_describe(e->ident, e->choices, sizeof e->choices, &e->choices_len);
    const char *rest = e->choices, *line = rest;
    int n;
    while (vd_next_line(&rest, &n)) {
        if (!strncmp(line, "pre-filter", 10) || !strncmp(line, "instrument lag", 14))
            vd_notice("%.*s", n, line);
        line = rest;
    }
}

/* The part of a row that belongs to its sample: time, index, gaps, and the estimator's
 * state (into the twin). Allocation-free with a twin. */
/* A row at sample index (from the run's start) and time t_us, its values NaN: the gap
 * (gap_samples missing since the previous row, flag G) and the outliers since then (O). */
static void begin_row(vd_est *e, vd_row *row, uint64_t index, int64_t t_us, uint64_t gap_samples)
{
    memset(row, 0, sizeof *row);
    row->t_us = t_us;
    row->index = index;
    row->run_s = (double)index / e->cfg->sample_rate;
    row->gap_samples = gap_samples;
    if (gap_samples)
        row->flags |= VD_FLAG_GAP;
    if (e->outlier_since_row)
        row->flags |= VD_FLAG_OUTLIER;
    e->outlier_since_row = 0;
    for (size_t k = 0; k < VD_MAX_PARAMS; k++)
        row->theta[k] = row->se[k] = row->freq[k] = row->freq_se[k] = row->zeta[k] = row->zeta_se[k] =
            row->change_stat[k] = row->change_mdc[k] = NAN;
    for (size_t j = 0; j < VD_MAX_COVARIATES; j++)
        row->cov[j] = NAN;
}

static void start_row(vd_est *e, const vibid_record *rec, uint64_t rel, vd_row *row)
{
    begin_row(e, row, rel, vd_ns_to_us(rec->t_ns), e->gap_since_row);
    e->gap_since_row = 0;
    for (size_t j = 0; j < VD_MAX_COVARIATES; j++) {
        row->cov[j] = e->cov_n[j] ? e->cov_sum[j] / (double)e->cov_n[j] : NAN;
        e->cov_sum[j] = 0.0;
        e->cov_n[j] = 0;
    }
    /* a failure cannot happen (twin_create checked the form); if it did, the row says E */
    e->sync_status = e->twin ? vibid_ident_twin_sync(e->twin, e->ident) : VIBID_OK;
}

/* The library's row (vibid/report.h) written into the track row's arrays. */
static vibid_report_row_out report_out(vd_row *row)
{
    return (vibid_report_row_out){.theta = row->theta,
                                  .se = row->se,
                                  .freq = row->freq,
                                  .freq_se = row->freq_se,
                                  .zeta = row->zeta,
                                  .zeta_se = row->zeta_se};
}

void vd_est_finish_row(vd_est *e, vd_row *row)
{
    note_new_choices(e);
    /* The library's row (vibid/report.h): estimate, covariance, modes, plausibility and
     * quality, the same checks as the Python binding's. */
    vibid_report_row_out out = report_out(row);
    if (e->sync_status != VIBID_OK)
        (void)vibid_report_no_estimate(e->report, e->sync_status, &out);
    else
        (void)vibid_report_row(e->report, e->twin ? e->twin : e->ident, &out); /* arguments checked at init */
    if (!(out.flags & VIBID_ROW_NOEST))
        e->pref_ready = true; /* the log tells of the reference at the first estimate */
    row->est_status = (int)out.est_status;
    row->implausible = out.implausible;
    row->flags |= out.flags;
    if (out.flags & VIBID_ROW_NOEST)
        e->est_errors++;
    if (out.flags & VIBID_ROW_IMPLAUSIBLE) {
        snprintf(e->why, sizeof e->why, "%s", out.why);
        e->implausible_rows++;
    }
    e->rows++;
    e->last = *row;
    e->have_last = true;
}

void vd_est_refined_row(vd_est *e, vd_row *row, uint64_t index, int64_t t_us, const double *theta, const double *se,
                        const double *cov, unsigned quality, uint64_t n_samples)
{
    memset(row, 0, sizeof *row);
    row->t_us = t_us;
    row->index = index;
    row->run_s = (double)index / e->cfg->sample_rate;
    row->flags = VD_FLAG_REFINED;
    for (size_t j = 0; j < VD_MAX_COVARIATES; j++)
        row->cov[j] = NAN;
    /* the library's row checks (vibid/report.h), as for every recursive row */
    vibid_report_row_out out = report_out(row);
    for (size_t k = 0; k < VD_MAX_PARAMS; k++)
        row->theta[k] = row->se[k] = row->freq[k] = row->freq_se[k] = row->zeta[k] = row->zeta_se[k] =
            row->change_stat[k] = row->change_mdc[k] = NAN;
    (void)vibid_report_estimate(e->report, theta, se, cov, quality, n_samples, &out); /* arguments checked at init */
    row->est_status = (int)out.est_status;
    row->implausible = out.implausible;
    row->flags |= out.flags;
    if (out.flags & VIBID_ROW_IMPLAUSIBLE) {
        snprintf(e->why, sizeof e->why, "%s", out.why);
        e->implausible_rows++;
    }
    e->rows++;
    e->last = *row;
    e->have_last = true;
}

void vd_est_oma_row(vd_est *e, vd_row *row, const vd_omat_result *res, uint64_t missing)
{
    begin_row(e, row, res->end_index, res->end_t_us, missing);
    for (size_t j = 0; j < e->cfg->n_covariates; j++)
        row->cov[j] = res->cov[j];
    for (size_t k = 0; k < e->p; k++) {
        row->theta[k] = res->theta[k];
        row->se[k] = res->se[k];
        if (isfinite(row->theta[k]) && !(isfinite(row->se[k]) && row->se[k] > 0.0))
            row->flags |= VD_FLAG_SE_INVALID;
    }
    if (!res->found) {
        row->flags |= VD_FLAG_NOEST;
        row->est_status = (int)VIBID_E_INSUFFICIENT_DATA;
        e->est_errors++;
    }
    e->rows++;
    e->last = *row;
    e->have_last = true;
}

int vd_est_record(vd_est *e, const vibid_record *rec, vd_row *row)
{
    if (rec->kind == VIBID_REC_FAULT)
        return 0;
    if (!e->started) {
        e->started = true;
        e->first_index = rec->index;
        e->next_index = rec->index;
        e->next_emit = rec->index + (e->cfg->decimation - 1);
    }
    if (rec->index > e->next_index) /* records lost on the way (ring overflow) */
        note_gap(e, rec->index - e->next_index);
    if (rec->index < e->next_index) /* cannot happen with a conforming source: skip */
        return 0;
    if (rec->kind == VIBID_REC_GAP) {
        note_gap(e, rec->count);
        e->next_index = rec->index + rec->count;
        return 0;
    }
    e->next_index = rec->index + 1;
    for (size_t j = 0; j < e->cfg->n_covariates && e->ident; j++) { /* the row's covariates: their block mean */
        double v = rec->values[e->cfg->cov_chan[j]];
        if (isfinite(v)) {
            e->cov_sum[j] += v;
            e->cov_n[j]++;
        }
    }
    if (!e->outl)
        model_values(e, rec, e->chan); /* else vd_est_next put them there, glitches as NaN */
    else if (e->rel_outliers)
        note_outlier(e, rec);
    if (!e->ident) { /* output-only: the caller hands e->chan to the mode tracker */
        e->samples++;
        return 0;
    }
    vibid_status st = vibid_ident_push(e->ident, e->chan);
    e->last_push_status = (int)st;
    if (st != VIBID_OK && !e->rel_outliers)
        e->push_errors++; /* non-finite value: the library restarted the window itself */
    e->samples++;
    if (rec->index < e->next_emit)
        return 0;
    uint64_t rel = rec->index - e->first_index, dec = e->cfg->decimation;
    uint64_t next = (rel / dec) * dec + (dec - 1); /* last index of rel's block */
    if (next <= rel)
        next += dec;
    e->next_emit = e->first_index + next;
    if (e->samples < e->cfg->warmup_samples)
        return 0;
    start_row(e, rec, rel, row);
    return 1;
}

int vd_est_row_due(const vd_est *e, const vibid_record *rec)
{
    return rec->kind != VIBID_REC_SAMPLE || !e->started || rec->index >= e->next_emit;
}
