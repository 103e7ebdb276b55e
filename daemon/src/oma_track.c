/* oma_track.c: see oma_track.h. */
#include "oma_track.h"
#include "clock.h"

#include <complex.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static void omat_job(void *arg);

int vd_omat_init(vd_omat *o, const vd_config *cfg, char *err, size_t cap)
{
    memset(o, 0, sizeof *o);
    if (!cfg->oma.on)
        return 0;
    const vd_oma_config *a = &cfg->oma;
    const double fa = cfg->sample_rate;
    o->cfg = cfg;
    o->nch = cfg->n_channels;
    o->ncov = cfg->n_covariates;
    o->every_n = (uint64_t)fmax(1.0, round(a->every_s * fa));
    /* the window in whole blocks, at most window_s long: rows every ceil(window / every)
     * periods apart then have disjoint windows (the change test's rows, oma_track.h) */
    const double window_n = floor(a->window_s * fa + 1e-6);
    o->max_blocks = (size_t)fmax(2.0, round(a->window_s / a->block_s));
    o->block_n = (uint64_t)fmax(4.0 * a->block_rows, floor(window_n / (double)o->max_blocks));
    vibid_oma_config oc;
    vibid_oma_config_init(&oc, fa, o->nch);
    oc.n_refs = a->n_refs;
    oc.refs = a->n_refs ? a->refs : NULL;
    oc.block_rows = a->block_rows;
    oc.max_order = a->max_order;
    oc.block_samples = (size_t)o->block_n;
    oc.max_blocks = o->max_blocks;
    oc.max_damping = a->max_damping;
    o->oma = vibid_oma_create(&oc);
    if (!o->oma) {
        snprintf(err, cap, "%s: oma: %s", cfg->path, vibid_last_error());
        return -1;
    }
    /* the ring: two periods and a block, so that the worker may be one period late */
    const uint64_t ring_n = 2 * o->every_n + o->block_n + 1024;
    o->chunk_n = o->block_n < 65536 ? o->block_n : 65536;
    const size_t w = o->nch + o->ncov, slots = o->max_blocks + 1;
    o->modes_cap = 256;
    if (vd_sample_ring_init(&o->ring, ring_n, w) || !(o->buf = malloc(o->chunk_n * w * sizeof *o->buf)) ||
        !(o->cov_sum = calloc(slots * (o->ncov ? o->ncov : 1), sizeof *o->cov_sum)) ||
        !(o->cov_cnt = calloc(slots * (o->ncov ? o->ncov : 1), sizeof *o->cov_cnt)) ||
        !(o->modes = malloc(o->modes_cap * sizeof *o->modes)) ||
        !(o->shape_re = malloc(o->modes_cap * o->nch * sizeof *o->shape_re)) ||
        !(o->shape_im = malloc(o->modes_cap * o->nch * sizeof *o->shape_im)) ||
        !(o->ref_re = calloc(a->n_modes * o->nch, sizeof *o->ref_re)) ||
        !(o->ref_im = calloc(a->n_modes * o->nch, sizeof *o->ref_im))) {
        snprintf(err, cap, "oma: out of memory for %llu samples of %zu channels", (unsigned long long)ring_n, w);
        vd_omat_fini(o);
        return -1;
    }
    if (vd_worker_init(&o->worker, "vibidd-oma", omat_job, o, err, cap)) {
        vd_omat_fini(o);
        return -1;
    }
    o->on = true;
    return 0;
}

int vd_omat_start(vd_omat *o, char *err, size_t cap)
{
    return o->on ? vd_worker_start(&o->worker, err, cap) : 0;
}

void vd_omat_fini(vd_omat *o)
{
    vd_worker_fini(&o->worker);
    vibid_oma_destroy(o->oma);
    vd_sample_ring_fini(&o->ring);
    free(o->buf);
    free(o->cov_sum);
    free(o->cov_cnt);
    free(o->modes);
    free(o->shape_re);
    free(o->shape_im);
    free(o->ref_re);
    free(o->ref_im);
    memset(o, 0, sizeof *o);
}

void vd_omat_push(vd_omat *o, const double *responses, const double *record_values)
{
    double x[VIBID_DRV_MAX_CHANNELS + VD_MAX_COVARIATES];
    for (size_t i = 0; i < o->nch; i++)
        x[i] = responses[i];
    for (size_t j = 0; j < o->ncov; j++)
        x[o->nch + j] = record_values[o->cfg->cov_chan[j]];
    vd_sample_ring_push(&o->ring, x);
}

void vd_omat_gap(vd_omat *o)
{
    double x[VIBID_DRV_MAX_CHANNELS + VD_MAX_COVARIATES];
    for (size_t i = 0; i < o->nch + o->ncov; i++)
        x[i] = NAN;
    vd_sample_ring_push(&o->ring, x);
}

/* The request's fields; false (counted) when the worker is not idle. */
static bool prepare(vd_omat *o, uint64_t end_index, int64_t end_t_us)
{
    if (!o->on)
        return false;
    if (vd_worker_busy(&o->worker) || vd_worker_done(&o->worker)) {
        o->skipped_busy++;
        return false;
    }
    o->req_end = vd_sample_ring_written(&o->ring);
    o->req_end_index = end_index;
    o->req_end_t_us = end_t_us;
    return true;
}

bool vd_omat_request(vd_omat *o, uint64_t end_index, int64_t end_t_us)
{
    return prepare(o, end_index, end_t_us) && vd_worker_request(&o->worker);
}

bool vd_omat_run_here(vd_omat *o, uint64_t end_index, int64_t end_t_us)
{
    return prepare(o, end_index, end_t_us) && vd_worker_run_here(&o->worker);
}

bool vd_omat_ready(const vd_omat *o)
{
    return o->on && vd_worker_done(&o->worker);
}

const vd_omat_result *vd_omat_take(vd_omat *o)
{
    if (!o->on || !vd_worker_done(&o->worker))
        return NULL;
    o->lost_samples += o->res.lost_samples;
    if (o->res.identified) {
        o->done++;
        o->last_duration_s = o->res.duration_s;
        if (!o->res.found)
            o->windows_without++;
    }
    return &o->res;
}

void vd_omat_release(vd_omat *o)
{
    vd_worker_release(&o->worker);
}

bool vd_omat_busy(const vd_omat *o)
{
    return o->on && vd_worker_busy(&o->worker);
}

void vd_omat_wait(vd_omat *o)
{
    if (o->on)
        vd_worker_wait(&o->worker);
}

/* ---- the worker's side ---- */

/* The covariates of the chunk's samples [0, n) into the per-block sums (the block of each
 * sample by o->pushed, before the chunk is pushed). */
static void add_covariates(vd_omat *o, uint64_t n)
{
    const size_t slots = o->max_blocks + 1, q = o->ncov;
    for (uint64_t k = 0; k < n; k++) {
        const uint64_t s = o->pushed + k;
        const size_t slot = (size_t)((s / o->block_n) % slots);
        if (s % o->block_n == 0)
            for (size_t j = 0; j < q; j++) /* a new block reuses the slot */
                o->cov_sum[slot * q + j] = o->cov_cnt[slot * q + j] = 0.0;
        for (size_t j = 0; j < q; j++) {
            const double v = o->buf[(o->nch + j) * o->chunk_n + k];
            if (isfinite(v)) {
                o->cov_sum[slot * q + j] += v;
                o->cov_cnt[slot * q + j] += 1.0;
            }
        }
    }
}

/* Samples lost to the ring: one gap for the covariances (no product spans them). */
static void push_gap(vd_omat *o)
{
    double nan_row[VIBID_DRV_MAX_CHANNELS];
    for (size_t i = 0; i < o->nch; i++)
        nan_row[i] = NAN;
    vibid_oma_push(o->oma, nan_row); /* VIBID_E_NONFINITE by design */
    o->pushed++;
}

/* Moves the ring's samples [consumed, end) into the covariance blocks. */
static void consume(vd_omat *o, uint64_t end)
{
    const uint64_t cap = o->ring.cap;
    if (end > o->consumed + cap - o->block_n) { /* fell behind: the oldest are gone or going */
        const uint64_t from = end - (cap - o->block_n);
        o->lost_since += from - o->consumed;
        o->consumed = from;
        push_gap(o);
    }
    while (o->consumed < end) {
        const uint64_t n = end - o->consumed < o->chunk_n ? end - o->consumed : o->chunk_n;
        if (!vd_sample_ring_copy(&o->ring, o->consumed, n, o->buf, (size_t)o->chunk_n)) {
            /* overwritten while copied (the worker was preempted for a long time): skip ahead */
            const uint64_t w = vd_sample_ring_written(&o->ring);
            const uint64_t from = w > cap - o->block_n ? w - (cap - o->block_n) : 0;
            const uint64_t skip = (from > o->consumed ? from : o->consumed + n) - o->consumed;
            o->lost_since += skip;
            o->consumed += skip;
            push_gap(o);
            continue;
        }
        add_covariates(o, n);
        vibid_oma_push_block(o->oma, (size_t)n, o->buf, (size_t)o->chunk_n, NULL);
        o->pushed += n;
        o->consumed += n;
    }
}

/* MAC of two complex shapes (rows ja of (are, aim) and jb of (bre, bim), nch long, stride
 * lda / ldb between channels). */
static double mac(const double *are, const double *aim, size_t lda, const double *bre, const double *bim, size_t ldb,
                  size_t nch)
{
    double complex ab = 0;
    double aa = 0, bb = 0;
    for (size_t i = 0; i < nch; i++) {
        const double complex a = are[i * lda] + I * aim[i * lda], b = bre[i * ldb] + I * bim[i * ldb];
        ab += conj(a) * b;
        aa += creal(conj(a) * a);
        bb += creal(conj(b) * b);
    }
    return aa > 0 && bb > 0 ? creal(ab * conj(ab)) / (aa * bb) : 0.0;
}

static void keep_shape(vd_omat *o, size_t j, size_t m)
{
    for (size_t i = 0; i < o->nch; i++) {
        o->ref_re[j * o->nch + i] = o->shape_re[i * o->modes_cap + m];
        o->ref_im[j * o->nch + i] = o->shape_im[i * o->modes_cap + m];
    }
    o->ref_f[j] = o->modes[m].freq_hz;
}

/* The tracked modes from the first identification (oma_track.h); false while they cannot be
 * (fewer modes than asked, or none near a nominal frequency: that one waits). */
static bool establish(vd_omat *o, size_t nm)
{
    const vd_oma_config *a = &o->cfg->oma;
    if (a->nominal_hz[0] > 0.0) {
        /* each tracked mode at the identified mode nearest its nominal frequency */
        bool all = true;
        for (size_t j = 0; j < a->n_modes; j++) {
            if (o->ref_f[j] > 0.0)
                continue;
            size_t best = nm;
            for (size_t m = 0; m < nm; m++) {
                const double d = fabs(o->modes[m].freq_hz - a->nominal_hz[j]) / a->nominal_hz[j];
                if (d <= a->match_freq && (best == nm || d < fabs(o->modes[best].freq_hz - a->nominal_hz[j]) /
                                                                 a->nominal_hz[j]))
                    best = m;
            }
            if (best < nm)
                keep_shape(o, j, best);
            else
                all = false;
        }
        return all;
    }
    if (nm < a->n_modes)
        return false;
    for (size_t j = 0; j < a->n_modes; j++) /* the modes come in order of frequency */
        keep_shape(o, j, j);
    return true;
}

/* Matches the window's modes to the tracked ones (oma_track.h) into the result. */
static void match(vd_omat *o, size_t nm)
{
    const vd_oma_config *a = &o->cfg->oma;
    vd_omat_result *res = &o->res;
    bool used[256] = {false}, matched[VD_OMA_MAX_MODES] = {false};
    const bool fresh = !o->established;
    if (fresh && establish(o, nm))
        o->established = true;
    res->established = o->established;
    for (;;) { /* greedy: the best remaining pair */
        double best = INFINITY;
        size_t bj = 0, bm = 0;
        for (size_t j = 0; j < a->n_modes; j++) {
            if (matched[j] || !(o->ref_f[j] > 0.0))
                continue;
            for (size_t m = 0; m < nm; m++) {
                if (used[m])
                    continue;
                const double df = fabs(o->modes[m].freq_hz - o->ref_f[j]) / o->ref_f[j];
                const double q = mac(o->ref_re + j * o->nch, o->ref_im + j * o->nch, 1, o->shape_re + m,
                                     o->shape_im + m, o->modes_cap, o->nch);
                if (df > a->match_freq || q < a->match_mac)
                    continue;
                const double cost = df + (1.0 - q);
                if (cost < best) {
                    best = cost;
                    bj = j;
                    bm = m;
                }
            }
        }
        if (!isfinite(best))
            break;
        matched[bj] = used[bm] = true;
        const vibid_oma_mode *md = &o->modes[bm];
        res->theta[2 * bj] = md->freq_hz;
        res->se[2 * bj] = md->freq_se;
        res->theta[2 * bj + 1] = md->zeta;
        res->se[2 * bj + 1] = md->zeta_se;
        res->found++;
        keep_shape(o, bj, bm);
    }
    if (!o->established)
        snprintf(res->reason, sizeof res->reason,
                 a->nominal_hz[0] > 0.0
                     ? "not every tracked mode found near its expected frequency yet (%zu modes identified)"
                     : "fewer modes identified (%zu) than oma.modes asks for: the tracked modes are not established yet",
                 nm);
    else if (!res->found)
        snprintf(res->reason, sizeof res->reason, "none of the %zu modes identified continues a tracked mode", nm);
}

static void omat_job(void *arg)
{
    vd_omat *o = arg;
    vd_omat_result *res = &o->res;
    const double t0 = vd_mono_s();
    res->filling = res->identified = res->established = false;
    res->reason[0] = '\0';
    res->end_index = o->req_end_index;
    res->end_t_us = o->req_end_t_us;
    res->found = res->n_identified = 0;
    for (size_t k = 0; k < VD_MAX_PARAMS; k++)
        res->theta[k] = res->se[k] = NAN;
    consume(o, o->req_end);
    res->lost_samples = o->lost_since;
    o->lost_since = 0;
    /* the covariates over the window's complete blocks */
    const size_t slots = o->max_blocks + 1, q = o->ncov;
    const uint64_t complete = o->pushed / o->block_n;
    for (size_t j = 0; j < q; j++) {
        double s = 0, c = 0;
        for (uint64_t b = complete > o->max_blocks ? complete - o->max_blocks : 0; b < complete; b++) {
            s += o->cov_sum[(b % slots) * q + j];
            c += o->cov_cnt[(b % slots) * q + j];
        }
        res->cov[j] = c > 0 ? s / c : NAN;
    }
    vibid_oma_stats st;
    vibid_oma_get_stats(o->oma, &st);
    res->window_samples = (uint64_t)st.blocks_complete * o->block_n;
    if (st.blocks_complete < o->max_blocks) {
        res->filling = true;
        snprintf(res->reason, sizeof res->reason, "the window is filling: %zu of %zu blocks of %.6g s",
                 st.blocks_complete, o->max_blocks, (double)o->block_n / o->cfg->sample_rate);
        res->duration_s = vd_mono_s() - t0;
        return;
    }
    vibid_status rc = vibid_oma_identify(o->oma);
    size_t nm = 0;
    if (rc == VIBID_OK)
        rc = vibid_oma_get_modes(o->oma, o->modes_cap, &nm, o->modes, o->shape_re, o->shape_im);
    if (rc != VIBID_OK) {
        snprintf(res->reason, sizeof res->reason, "identification failed: %s", vibid_last_error());
        res->duration_s = vd_mono_s() - t0;
        return;
    }
    if (nm > o->modes_cap)
        nm = o->modes_cap;
    res->identified = true;
    res->n_identified = nm;
    match(o, nm);
    res->duration_s = vd_mono_s() - t0;
}
