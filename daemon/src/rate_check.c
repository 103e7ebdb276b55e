/* rate_check.c: see rate_check.h. */

#include "rate_check.h"

#include "log.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <vibid_drivers/source.h>

int vd_rate_mode_parse(const char *s)
{
    if (!strcmp(s, "error"))
        return VD_RATE_MODE_ERROR;
    if (!strcmp(s, "warn"))
        return VD_RATE_MODE_WARN;
    if (!strcmp(s, "off"))
        return VD_RATE_MODE_OFF;
    return -1;
}

/* ------------------------------------------------------------- estimation ---- */

static void swap_d(double *a, double *b)
{
    double t = *a;
    *a = *b;
    *b = t;
}

/* The element of rank n/2 (the upper median) of a[0..n-1], n >= 1; reorders a.
 * Quickselect with a median-of-three pivot: O(n) on average, also for sorted input. */
static double median_inplace(double *a, size_t n)
{
    size_t lo = 0, hi = n - 1, want = n / 2;
    while (hi > lo) {
        size_t mid = lo + (hi - lo) / 2;
        if (a[mid] < a[lo])
            swap_d(&a[mid], &a[lo]);
        if (a[hi] < a[lo])
            swap_d(&a[hi], &a[lo]);
        if (a[hi] < a[mid])
            swap_d(&a[hi], &a[mid]);
        double pivot = a[mid];
        size_t i = lo, j = hi;
        while (i <= j) {
            while (a[i] < pivot)
                i++;
            while (a[j] > pivot)
                j--;
            if (i <= j) {
                swap_d(&a[i], &a[j]);
                i++;
                if (j == 0)
                    break;
                j--;
            }
        }
        if (want <= j)
            hi = j;
        else if (want >= i)
            lo = i;
        else
            return a[want];
    }
    return a[want];
}

/* Means of the kept points of stretch seg[s]..seg[s+1]; returns their number (0: none). */
static size_t stretch_means(const double *x, const double *y, const unsigned char *keep, const size_t *seg, size_t s,
                            double *mx, double *my)
{
    double sx = 0, sy = 0;
    size_t m = 0;
    for (size_t i = seg[s]; i < seg[s + 1]; i++)
        if (keep[i]) {
            sx += x[i];
            sy += y[i];
            m++;
        }
    if (m) {
        *mx = sx / (double)m;
        *my = sy / (double)m;
    }
    return m;
}

/* Pooled least squares over the kept points: common slope, one intercept per stretch.
 * seg[s]..seg[s+1] are the stretches. Fills *slope, *se; -1 if no stretch has two kept
 * points with different x. Intercepts (per stretch) go to icpt. */
static int pooled_fit(const double *x, const double *y, const unsigned char *keep, const size_t *seg, size_t nseg,
                      double *slope, double *se, double *icpt)
{
    double sxx = 0, sxy = 0, mx = 0, my = 0;
    size_t used = 0, groups = 0;
    for (size_t s = 0; s < nseg; s++) {
        size_t m = stretch_means(x, y, keep, seg, s, &mx, &my);
        if (m == 0)
            continue;
        for (size_t i = seg[s]; i < seg[s + 1]; i++)
            if (keep[i]) {
                sxx += (x[i] - mx) * (x[i] - mx);
                sxy += (x[i] - mx) * (y[i] - my);
            }
        used += m;
        groups++;
    }
    if (!(sxx > 0))
        return -1;
    double b = sxy / sxx, ss = 0;
    for (size_t s = 0; s < nseg; s++) {
        if (stretch_means(x, y, keep, seg, s, &mx, &my) == 0)
            continue;
        icpt[s] = my - b * mx;
        for (size_t i = seg[s]; i < seg[s + 1]; i++)
            if (keep[i]) {
                double r = y[i] - icpt[s] - b * x[i];
                ss += r * r;
            }
    }
    double dof = (double)used - (double)groups - 1.0;
    *slope = b;
    *se = dof > 0 ? sqrt(ss / dof / sxx) : INFINITY;
    return 0;
}

int vd_rate_estimate(const uint64_t *k, const int64_t *t_ns, size_t n, double split_min_s, vd_rate_fit *fit,
                     const char **why)
{
    const char *dummy;
    if (!why)
        why = &dummy;
    memset(fit, 0, sizeof *fit);
    fit->n = n;
    if (n < VD_RATE_MIN_POINTS) {
        *why = "too few samples";
        return -1;
    }
    fit->k_first = k[0];
    fit->k_last = k[n - 1];
    for (size_t i = 1; i < n; i++)
        if (k[i] <= k[i - 1]) {
            *why = "sample indices do not increase";
            return -1;
        }
    /* x: index, y: time in s, both relative to the first point (double keeps ns of a
     * window; absolute epoch nanoseconds would not fit a double's 53 bits). */
    double *x = malloc(n * sizeof *x), *y = malloc(n * sizeof *y), *res = malloc(n * sizeof *res);
    double *w = malloc(3 * n * sizeof *w), *icpt = malloc(n * sizeof *icpt);
    size_t *seg = malloc((n + 1) * sizeof *seg);
    unsigned char *keep = malloc(n);
    int rc = -1;
    if (!x || !y || !res || !w || !icpt || !seg || !keep) {
        *why = "out of memory";
        goto out;
    }
    for (size_t i = 0; i < n; i++) {
        x[i] = (double)(k[i] - k[0]);
        y[i] = (double)(t_ns[i] - t_ns[0]) * 1e-9;
    }
    /* 1. stretches: a rough period from consecutive samples, cut where a step is longer
     *    than its index step explains */
    for (size_t i = 0; i + 1 < n; i++)
        w[i] = (y[i + 1] - y[i]) / (x[i + 1] - x[i]);
    double h1 = median_inplace(w, n - 1);
    if (!(h1 > 0))
        h1 = y[n - 1] / x[n - 1];
    if (!(h1 > 0)) {
        *why = "the times do not advance";
        goto out;
    }
    double cut = fmax(0.5 * h1, split_min_s);
    size_t nseg = 0;
    seg[nseg++] = 0;
    for (size_t i = 1; i < n; i++)
        if ((y[i] - y[i - 1]) - (x[i] - x[i - 1]) * h1 > cut)
            seg[nseg++] = i;
    seg[nseg] = n;
    /* 2. robust start: median slope over pairs at lags L/16, L/8, L/4 of each stretch */
    size_t np = 0;
    for (size_t s = 0; s < nseg; s++) {
        size_t a = seg[s], L = seg[s + 1] - a;
        if (L < 2)
            continue;
        size_t lags[3] = {L / 16, L / 8, L / 4};
        for (int j = 0; j < 3; j++) {
            size_t m = lags[j] ? lags[j] : 1;
            if (j > 0 && m == (lags[j - 1] ? lags[j - 1] : 1))
                continue;
            for (size_t i = a; i + m < a + L; i++)
                w[np++] = (y[i + m] - y[i]) / (x[i + m] - x[i]);
        }
    }
    if (np == 0) {
        *why = "no two consecutive samples without a time gap";
        goto out;
    }
    double h0 = median_inplace(w, np);
    if (!(h0 > 0)) {
        *why = "the times do not advance";
        goto out;
    }
    for (size_t s = 0; s < nseg; s++) {
        size_t a = seg[s], L = seg[s + 1] - a;
        for (size_t i = 0; i < L; i++)
            w[i] = y[a + i] - h0 * x[a + i];
        icpt[s] = median_inplace(w, L);
    }
    /* 3. + 4. leave out the points far from the line, fit, and once more from the fit */
    double slope = h0, se = INFINITY;
    size_t used = 0;
    for (int pass = 0; pass < 2; pass++) {
        for (size_t s = 0; s < nseg; s++)
            for (size_t i = seg[s]; i < seg[s + 1]; i++)
                res[i] = y[i] - icpt[s] - slope * x[i];
        for (size_t i = 0; i < n; i++)
            w[i] = fabs(res[i]);
        double sigma = 1.4826 * median_inplace(w, n);
        double thr = fmax(5.0 * sigma, fmax(0.01 * slope, 2e-6));
        used = 0;
        for (size_t i = 0; i < n; i++) {
            keep[i] = fabs(res[i]) <= thr;
            used += keep[i];
        }
        if (2 * used < n) {
            *why = "the times of more than half of the samples are irregular";
            goto out;
        }
        if (pooled_fit(x, y, keep, seg, nseg, &slope, &se, icpt)) {
            *why = "no stretch of samples to fit";
            goto out;
        }
    }
    if (!(slope > 0)) {
        *why = "the times do not advance";
        goto out;
    }
    fit->period_s = slope;
    fit->rate_hz = 1.0 / slope;
    fit->rel_se = se / slope;
    fit->used = used;
    fit->segments = nseg;
    rc = 0;
out:
    free(x);
    free(y);
    free(res);
    free(w);
    free(icpt);
    free(seg);
    free(keep);
    return rc;
}

/* ---------------------------------------------------------------- decision ---- */

struct vd_rate_check {
    double stand_hz, split_min_s;
    char who[VD_PATH_MAX + 32], basis[96], stand[VD_PATH_MAX + 32], fix[160];
    uint64_t *k;
    int64_t *t;                 /* 2 windows: [0, n_prev) the suspect one, then the current */
    size_t n_prev, n;
    bool have_k0;
    uint64_t k0;                /* first index of the stream: samples are numbered from it */
    unsigned windows;
    bool prev_off;
    vd_rate_fit prev_fit;
    bool done;
    char msg[3 * VD_PATH_MAX];
};

vd_rate_check *vd_rate_check_create(double stand_hz, double split_min_s, const char *who, const char *basis,
                                    const char *stand, const char *fix)
{
    vd_rate_check *c = calloc(1, sizeof *c);
    if (!c)
        return NULL;
    c->k = malloc(2 * VD_RATE_WINDOW_MAX * sizeof *c->k);
    c->t = malloc(2 * VD_RATE_WINDOW_MAX * sizeof *c->t);
    if (!c->k || !c->t) {
        vd_rate_check_destroy(c);
        return NULL;
    }
    c->stand_hz = stand_hz;
    c->split_min_s = split_min_s;
    snprintf(c->who, sizeof c->who, "%s", who);
    snprintf(c->basis, sizeof c->basis, "%s", basis);
    snprintf(c->stand, sizeof c->stand, "%s", stand);
    snprintf(c->fix, sizeof c->fix, "%s", fix);
    return c;
}

void vd_rate_check_destroy(vd_rate_check *c)
{
    if (!c)
        return;
    free(c->k);
    free(c->t);
    free(c);
}

bool vd_rate_check_done(const vd_rate_check *c) { return c->done; }

const char *vd_rate_check_message(const vd_rate_check *c) { return c->msg; }

/* "sample rate 1000.0 Hz (from the time column, samples 0..3999)" */
static int describe(const vd_rate_check *c, const vd_rate_fit *f, char *buf, size_t cap)
{
    char rate[64];
    if (f->rate_hz >= 100)
        snprintf(rate, sizeof rate, "%.1f", f->rate_hz);
    else
        snprintf(rate, sizeof rate, "%.4g", f->rate_hz);
    return snprintf(buf, cap, "sample rate %s Hz (%s, samples %llu..%llu)", rate, c->basis,
                    (unsigned long long)(f->k_first - c->k0), (unsigned long long)(f->k_last - c->k0));
}

static vd_rate_event decide(vd_rate_check *c, vd_rate_event ev, const vd_rate_fit *f)
{
    char d[256];
    describe(c, f, d, sizeof d);
    double off = 100.0 * (f->rate_hz / c->stand_hz - 1.0);
    if (fabs(off) < 0.005)
        off = 0.0; /* "+0.00 %", not "-0.00 %" */
    switch (ev) {
    case VD_RATE_PASS:
        snprintf(c->msg, sizeof c->msg, "%s: %s fits the stand's sample_rate %g Hz (%s): %+.2f %%", c->who, d,
                 c->stand_hz, c->stand, off);
        break;
    case VD_RATE_FAIL:
        snprintf(c->msg, sizeof c->msg, "%s: %s is %.1f %% off the stand's sample_rate %g Hz (%s): %s", c->who, d,
                 fabs(off), c->stand_hz, c->stand, c->fix);
        break;
    case VD_RATE_SUSPECT:
        snprintf(c->msg, sizeof c->msg,
                 "%s: %s looks %.1f %% off the stand's sample_rate %g Hz (%s); the next %g s decide before it is "
                 "refused",
                 c->who, d, fabs(off), c->stand_hz, c->stand, VD_RATE_WINDOW_S);
        break;
    default:
        break;
    }
    if (ev == VD_RATE_PASS || ev == VD_RATE_FAIL)
        c->done = true;
    return ev;
}

static vd_rate_event unchecked(vd_rate_check *c, const char *why)
{
    snprintf(c->msg, sizeof c->msg, "%s: sample rate not checked against the stand's %g Hz (%s): %s", c->who,
             c->stand_hz, c->stand, why);
    c->done = true;
    return VD_RATE_UNCHECKED;
}

/* Evaluates the current window [n_prev, n_prev + n). at_end: the stream is over. */
static vd_rate_event evaluate(vd_rate_check *c, bool at_end)
{
    vd_rate_fit f;
    const char *why = NULL;
    int ok = vd_rate_estimate(c->k + c->n_prev, c->t + c->n_prev, c->n, c->split_min_s, &f, &why);
    c->windows++;
    /* rel: the window's rate relative to the stand's - 1; u: VD_RATE_SE_FACTOR standard errors of it */
    double rel = 0, u = 0;
    char scatter[160];
    if (ok == 0) {
        rel = f.rate_hz / c->stand_hz - 1.0;
        u = VD_RATE_SE_FACTOR * f.rel_se * (f.rate_hz / c->stand_hz);
        if (fabs(rel) + u <= VD_RATE_TOLERANCE)
            return decide(c, VD_RATE_PASS, &f);
        if (!(fabs(rel) - u > VD_RATE_TOLERANCE)) {
            snprintf(scatter, sizeof scatter, "the times scatter too much to decide at %g %% (%.6g Hz +- %.3g Hz)",
                     100.0 * VD_RATE_TOLERANCE, f.rate_hz, u * c->stand_hz);
            why = scatter;
            ok = -1;
        }
    }
    if (ok == 0) {
        /* clearly off: refused when the window before was off in the same direction */
        bool agree = c->prev_off && (rel > 0) == (c->prev_fit.rate_hz > c->stand_hz);
        if (agree || at_end) {
            /* refused: with a suspect window before, the fit over both */
            vd_rate_fit un;
            if (agree && vd_rate_estimate(c->k, c->t, c->n_prev + c->n, c->split_min_s, &un, NULL) == 0 &&
                fabs(un.rate_hz / c->stand_hz - 1.0) > VD_RATE_TOLERANCE)
                f = un;
            return decide(c, VD_RATE_FAIL, &f);
        }
        if (c->windows >= VD_RATE_MAX_WINDOWS) {
            char d[256], w[512];
            describe(c, &f, d, sizeof d);
            snprintf(w, sizeof w, "%u windows of %g s disagree (the last: %s)", c->windows, VD_RATE_WINDOW_S, d);
            return unchecked(c, w);
        }
        /* suspect: keep it, the next window decides */
        memmove(c->k, c->k + c->n_prev, c->n * sizeof *c->k);
        memmove(c->t, c->t + c->n_prev, c->n * sizeof *c->t);
        c->n_prev = c->n;
        c->n = 0;
        c->prev_off = true;
        c->prev_fit = f;
        return decide(c, VD_RATE_SUSPECT, &f);
    }
    /* no estimate from this window */
    if (at_end || c->windows >= VD_RATE_MAX_WINDOWS) {
        if (c->prev_off && at_end) /* nothing is left that could contradict the suspect window */
            return decide(c, VD_RATE_FAIL, &c->prev_fit);
        char w[256];
        snprintf(w, sizeof w, "%s (samples %llu..%llu)", why, (unsigned long long)(f.k_first - c->k0),
                 (unsigned long long)(f.k_last - c->k0));
        return unchecked(c, w);
    }
    c->prev_off = false;
    c->n_prev = 0;
    c->n = 0;
    return VD_RATE_PENDING;
}

vd_rate_event vd_rate_check_feed(vd_rate_check *c, const vibid_record *rec)
{
    if (c->done || rec->kind == VIBID_REC_FAULT)
        return VD_RATE_PENDING;
    if (!c->have_k0) {
        c->have_k0 = true;
        c->k0 = rec->index;
    }
    if (rec->kind != VIBID_REC_SAMPLE)
        return VD_RATE_PENDING;
    size_t end = c->n_prev + c->n;
    if ((end > 0 && rec->index <= c->k[end - 1]) || rec->index < c->k0)
        return VD_RATE_PENDING; /* not newer than the last: not a point of the line */
    c->k[end] = rec->index;
    c->t[end] = rec->t_ns;
    c->n++;
    const int64_t span = rec->t_ns - c->t[c->n_prev];
    if ((c->n >= VD_RATE_WINDOW_MIN && span >= (int64_t)(VD_RATE_WINDOW_S * 1e9)) || c->n >= VD_RATE_WINDOW_MAX)
        return evaluate(c, false);
    return VD_RATE_PENDING;
}

vd_rate_event vd_rate_check_finish(vd_rate_check *c)
{
    if (c->done)
        return VD_RATE_PENDING;
    if (c->n >= VD_RATE_MIN_POINTS)
        return evaluate(c, true);
    if (c->prev_off)
        return decide(c, VD_RATE_FAIL, &c->prev_fit);
    char w[128];
    snprintf(w, sizeof w, "%zu samples are too few to estimate it (at least %d)", c->n, VD_RATE_MIN_POINTS);
    return unchecked(c, w);
}

/* --------------------------------------------------------- the daemon's uses ---- */

static void stand_label(const vd_config *cfg, char *buf, size_t cap)
{
    if (cfg->oma.on)
        snprintf(buf, cap, "oma.sample_rate in %s", cfg->path);
    else if (cfg->stand_file[0])
        snprintf(buf, cap, "%s", cfg->stand_file);
    else
        snprintf(buf, cap, "stand inline in %s", cfg->path);
}

vd_rate_check *vd_rate_check_create_live(const vd_config *cfg)
{
    char who[64], stand[VD_PATH_MAX + 32];
    snprintf(who, sizeof who, "socketcan %s", cfg->iface);
    stand_label(cfg, stand, sizeof stand);
    return vd_rate_check_create(cfg->sample_rate, VD_RATE_SPLIT_RX_S, who, "from the receive timestamps", stand,
                                "fix stand.sample_rate or the device's sample rate (a simulator slower than real "
                                "time: --rate-check warn)");
}

/* Logs a final or suspect event at its level; with mode warn a refusal is a warning. */
static void log_event(vd_rate_event ev, const char *msg, vd_rate_mode mode)
{
    switch (ev) {
    case VD_RATE_PASS:
        vd_info("%s", msg);
        break;
    case VD_RATE_SUSPECT:
        vd_warning("%s", msg);
        break;
    case VD_RATE_UNCHECKED:
        vd_warning("%s", msg);
        break;
    case VD_RATE_FAIL:
        if (mode == VD_RATE_MODE_WARN)
            vd_warning("%s (--rate-check warn: going on)", msg);
        break;
    default:
        break;
    }
}

int vd_rate_check_live(vd_rate_check *c, const vibid_record *rec, vd_rate_mode mode)
{
    vd_rate_event ev = vd_rate_check_feed(c, rec);
    if (ev == VD_RATE_PENDING)
        return 0;
    if (ev == VD_RATE_FAIL && mode == VD_RATE_MODE_ERROR) {
        vd_error("%s; stopping: configuration error (exit status 2)", vd_rate_check_message(c));
        return 1;
    }
    log_event(ev, vd_rate_check_message(c), mode);
    return 0;
}

int vd_rate_check_capture(const vd_config *cfg, const vibid_source_replay_config *rc, vd_rate_mode mode,
                          char *note, size_t note_cap, char *err, size_t cap)
{
    const bool check_only = note != NULL;
    if (note && note_cap)
        note[0] = '\0';
    if (mode == VD_RATE_MODE_OFF)
        return 0;
    const bool csv = rc->format == VIBID_REPLAY_CSV;
    char stand[VD_PATH_MAX + 32];
    stand_label(cfg, stand, sizeof stand);
    if (csv && !rc->chanmap.time_column[0]) {
        if (check_only)
            snprintf(note, note_cap, "%s: sample rate not checked: the CSV has no time column, its times are k / %g Hz "
                     "(the stand's)", rc->path, cfg->sample_rate);
        else
            vd_info("%s: sample rate not checked: the CSV has no time column, its times are k / %g Hz (the stand's)",
                    rc->path, cfg->sample_rate);
        return 0;
    }
    if (check_only && access(rc->path, R_OK) != 0) {
        snprintf(note, note_cap, "%s: cannot read the capture: its sample rate is checked when it is replayed",
                 rc->path);
        return 0;
    }
    vibid_source_replay_config pc = *rc;
    pc.paced = false;
    pc.speed = 1.0;
    if (csv)
        pc.sample_period_s = 0; /* the rows as they are: no gaps made from the stand's period */
    vibid_drv_error de = {0};
    vibid_source *src = vibid_source_open(&vibid_source_replay_ops, &pc, &de);
    if (!src) {
        snprintf(err, cap, "replay of %s: %s", rc->path, de.text);
        return -1;
    }
    char basis[96];
    if (csv)
        snprintf(basis, sizeof basis, "from the time column '%.40s'", rc->chanmap.time_column);
    else
        snprintf(basis, sizeof basis, "from the candump timestamps");
    /* A candump log holds log (receive) times: the same allowance for pauses as live CAN. */
    vd_rate_check *c = vd_rate_check_create(cfg->sample_rate, csv ? 0.0 : VD_RATE_SPLIT_RX_S, rc->path, basis,
                                            stand, "fix stand.sample_rate or the capture");
    enum { BATCH = 256 };
    vibid_record *recs = malloc(BATCH * sizeof *recs);
    if (!c || !recs) {
        vd_rate_check_destroy(c);
        free(recs);
        vibid_source_close(src);
        snprintf(err, cap, "out of memory");
        return -1;
    }
    vd_rate_event ev = VD_RATE_PENDING;
    while (!vd_rate_check_done(c)) {
        size_t n = 0;
        vibid_drv_status st = vibid_source_read(src, recs, BATCH, &n, 100, &de);
        for (size_t i = 0; i < n && !vd_rate_check_done(c); i++) {
            ev = vd_rate_check_feed(c, &recs[i]);
            if (ev == VD_RATE_SUSPECT && !check_only) /* the next window decides */
                vd_info("%s", vd_rate_check_message(c));
        }
        if (st != VIBID_DRV_OK && st != VIBID_DRV_E_AGAIN) {
            /* the end, or an error the run itself will report: decide with what was read */
            if (!vd_rate_check_done(c))
                ev = vd_rate_check_finish(c);
            break;
        }
    }
    int rcode = 0;
    if (ev == VD_RATE_FAIL && mode == VD_RATE_MODE_ERROR) {
        snprintf(err, cap, "%s", vd_rate_check_message(c));
        rcode = -1;
    } else if (check_only) {
        snprintf(note, note_cap, "%s%s", vd_rate_check_message(c),
                 ev == VD_RATE_FAIL ? " (--rate-check warn: going on)" : "");
    } else {
        log_event(ev, vd_rate_check_message(c), mode);
    }
    vd_rate_check_destroy(c);
    free(recs);
    vibid_source_close(src);
    return rcode;
}
