/* reference.c: see reference.h. */
#include "reference.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <vibid/identify.h>

static uint64_t fnv(uint64_t h, const void *p, size_t n)
{
    const unsigned char *b = p;
    for (size_t i = 0; i < n; i++) {
        h ^= b[i];
        h *= 0x100000001b3ull;
    }
    return h;
}

static uint64_t fnv_str(uint64_t h, const char *s) { return fnv(h, s, strlen(s) + 1); }

/* a number by its shortest exact text, so that the key does not depend on the layout of a
 * double in memory */
static uint64_t fnv_num(uint64_t h, double v)
{
    char t[40];
    snprintf(t, sizeof t, "%.17g", v);
    return fnv_str(h, t);
}

uint64_t vd_reference_key(const vd_config *cfg, const vd_cusum *c)
{
    uint64_t h = 0xcbf29ce484222325ull;
    h = fnv_str(h, vd_stand_name(cfg));
    h = fnv_num(h, cfg->sample_rate);
    for (size_t k = 0; k < cfg->n_params; k++)
        h = fnv_str(h, vd_param_name(cfg, k));
    h = fnv_str(h, vibid_estimator_name(cfg->method));
    h = fnv_num(h, cfg->forgetting);
    h = fnv_num(h, (double)cfg->decimation);
    if (cfg->oma.on) { /* output-only: what the modes' block estimates depend on */
        h = fnv_num(h, cfg->oma.window_s);
        h = fnv_num(h, cfg->oma.every_s);
        h = fnv_num(h, cfg->oma.block_s);
        h = fnv_num(h, (double)cfg->oma.block_rows);
        h = fnv_num(h, (double)cfg->oma.max_order);
        for (size_t i = 0; i < cfg->n_channels; i++)
            h = fnv_str(h, cfg->chanmap.ch[cfg->model_to_chan[i]].name);
    }
    h = fnv_num(h, cfg->prefilter_hz);
    h = fnv_num(h, (double)cfg->iv_lag);
    h = fnv_num(h, (double)cfg->difference_order);
    for (size_t i = 0; i < c->n; i++)
        h = fnv_str(h, vd_param_name(cfg, c->param[i]));
    /* the covariates the reference depends on (none: the key of a reference without them) */
    for (size_t j = 0; j < cfg->n_covariates; j++)
        h = fnv_str(h, cfg->chanmap.ch[cfg->cov_chan[j]].name);
    return h;
}

int vd_reference_save(const char *path, const vd_config *cfg, const vd_cusum *c, uint64_t learned_index,
                      double learned_time_s, char *err, size_t cap)
{
    vibid_change_reference ref[VD_MAX_PARAMS];
    if (!c->det || vibid_change_get_reference(c->det, ref) != VIBID_OK) {
        snprintf(err, cap, "%s: no reference to save", path);
        return -1;
    }
    char tmp[VD_PATH_MAX + 8];
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
    FILE *f = fopen(tmp, "we");
    if (!f) {
        snprintf(err, cap, "%s: cannot write: %s", tmp, strerror(errno));
        return -1;
    }
    fprintf(f,
            "# vibidd alarm reference: replaced only by vibidd --reference learn|forget (docs/vibidd.md)\n"
            "format=2\nstand=%s\nkey=%016llx\nlearned_index=%llu\nlearned_time_s=%.6f\n",
            vd_stand_name(cfg), (unsigned long long)vd_reference_key(cfg, c),
            (unsigned long long)learned_index, learned_time_s);
    for (size_t i = 0; i < c->n; i++) {
        const char *p = vd_param_name(cfg, c->param[i]);
        fprintf(f, "%s.mean=%.17g\n%s.block_sd=%.17g\n%s.n_mean=%.17g\n%s.n_sd=%.17g\n", p, ref[i].mean, p,
                ref[i].block_sd, p, ref[i].n_mean, p, ref[i].n_sd);
        const size_t q = cfg->n_covariates, T = ref[i].n_terms ? ref[i].n_terms : q;
        if (!q)
            continue;
        for (size_t j = 0; j < q; j++)
            fprintf(f, "%s.centre_%zu=%.17g\n%s.low_%zu=%.17g\n%s.high_%zu=%.17g\n%s.origin_%zu=%.17g\n", p, j,
                    ref[i].centre[j], p, j, ref[i].low[j], p, j, ref[i].high[j], p, j,
                    ref[i].n_terms ? ref[i].origin[j] : ref[i].centre[j]);
        fprintf(f, "%s.n_terms=%zu\n", p, T);
        for (size_t t = 0; t < T; t++) {
            /* the first form (n_terms 0) is linear from the centre: origin = centre, means 0 */
            fprintf(f, "%s.slope_%zu=%.17g\n%s.term_mean_%zu=%.17g\n", p, t, ref[i].slope[t], p, t,
                    ref[i].n_terms ? ref[i].term_mean[t] : 0.0);
            for (size_t l = 0; l < T; l++)
                fprintf(f, "%s.gram_inv_%zu_%zu=%.17g\n", p, t, l, ref[i].gram_inv[t * T + l]);
        }
    }
    bool ok = fflush(f) == 0 && fsync(fileno(f)) == 0;
    const int e = errno;
    if (fclose(f) != 0)
        ok = false;
    if (!ok || rename(tmp, path) != 0) {
        snprintf(err, cap, "%s: cannot write: %s", path, strerror(ok ? errno : e));
        unlink(tmp);
        return -1;
    }
    char dir[VD_PATH_MAX];
    vd_path_dir(path, dir, sizeof dir);
    const int dfd = open(dir, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (dfd >= 0) {
        (void)fsync(dfd); /* the rename itself on disk */
        close(dfd);
    }
    return 0;
}

/* The fields of a parameter's saved reference, each with a slot of its own (the load checks
 * that every slot a reference needs is there, once). Format 2: mean, block_sd, n_mean, n_sd
 * (slots 0-3); per covariate j centre_j, low_j, high_j, origin_j (4 + 4 j ..); n_terms (20);
 * per term t slope_t, term_mean_t (21 + 2 t ..); gram_inv_t_l (49 + 14 t + l). Format 1 (the
 * linear reference before the second-order terms: read, not written): per covariate slope_j,
 * centre_j, low_j, high_j and gram_inv_jl (one digit each), the reference's n_terms 0. */
#define REF_SLOTS (49 + VIBID_CHANGE_MAX_TERMS * VIBID_CHANGE_MAX_TERMS)

/* "name_<index>" of at most max: the index, or -1. */
static long field_index(const char *fld, const char *name, size_t max, const char **rest)
{
    size_t n = strlen(name);
    if (strncmp(fld, name, n) || fld[n] < '0' || fld[n] > '9')
        return -1;
    char *end;
    long v = strtol(fld + n, &end, 10);
    *rest = end;
    return v >= 0 && (size_t)v < max ? v : -1;
}

static double *ref_field(vibid_change_reference *r, int format, size_t q, double *n_terms, const char *fld,
                         unsigned *slot)
{
    static const char *const base[] = {"mean", "block_sd", "n_mean", "n_sd"};
    double *const base_dst[] = {&r->mean, &r->block_sd, &r->n_mean, &r->n_sd};
    for (unsigned b = 0; b < 4; b++)
        if (!strcmp(fld, base[b])) {
            *slot = b;
            return base_dst[b];
        }
    const char *rest;
    long j;
    if (format == 1) {
        static const char *const per[] = {"slope_", "centre_", "low_", "high_"};
        for (unsigned b = 0; b < 4; b++)
            if ((j = field_index(fld, per[b], q, &rest)) >= 0 && !*rest && rest == fld + strlen(per[b]) + 1) {
                double *const dst[] = {&r->slope[j], &r->centre[j], &r->low[j], &r->high[j]};
                *slot = (unsigned)(4 + 4 * j + b);
                return dst[b];
            }
        if (!strncmp(fld, "gram_inv_", 9) && fld[9] >= '0' && (size_t)(fld[9] - '0') < q && fld[10] >= '0' &&
            (size_t)(fld[10] - '0') < q && !fld[11]) {
            size_t a = (size_t)(fld[9] - '0'), l = (size_t)(fld[10] - '0');
            *slot = (unsigned)(49 + 14 * a + l);
            return &r->gram_inv[a * q + l];
        }
        return NULL;
    }
    static const char *const per[] = {"centre_", "low_", "high_", "origin_"};
    for (unsigned b = 0; b < 4; b++)
        if ((j = field_index(fld, per[b], q, &rest)) >= 0 && !*rest) {
            double *const dst[] = {&r->centre[j], &r->low[j], &r->high[j], &r->origin[j]};
            *slot = (unsigned)(4 + 4 * j + b);
            return dst[b];
        }
    if (!strcmp(fld, "n_terms")) {
        *slot = 20;
        return n_terms;
    }
    static const char *const term[] = {"slope_", "term_mean_"};
    for (unsigned b = 0; b < 2; b++)
        if ((j = field_index(fld, term[b], VIBID_CHANGE_MAX_TERMS, &rest)) >= 0 && !*rest) {
            double *const dst[] = {&r->slope[j], &r->term_mean[j]};
            *slot = (unsigned)(21 + 2 * j + b);
            return dst[b];
        }
    if ((j = field_index(fld, "gram_inv_", VIBID_CHANGE_MAX_TERMS, &rest)) >= 0 && *rest == '_') {
        const char *end;
        long l = field_index(rest, "_", VIBID_CHANGE_MAX_TERMS, &end);
        if (l >= 0 && !*end) {
            /* row-major T x T: T is known at the end (n_terms); kept at 14 x 14 until then */
            *slot = (unsigned)(49 + 14 * j + l);
            return &r->gram_inv[j * VIBID_CHANGE_MAX_TERMS + l];
        }
    }
    return NULL;
}

/* "a.mean" -> k of the alarmed parameter a and the field; -1 if no such parameter. */
static int field_of(const vd_config *cfg, const vd_cusum *c, const char *key, size_t *i, const char **field)
{
    const char *dot = strrchr(key, '.');
    if (!dot)
        return -1;
    for (size_t j = 0; j < c->n; j++) {
        const char *p = vd_param_name(cfg, c->param[j]);
        if (strlen(p) == (size_t)(dot - key) && !strncmp(p, key, (size_t)(dot - key))) {
            *i = j;
            *field = dot + 1;
            return 0;
        }
    }
    return -1;
}

int vd_reference_load(const char *path, const vd_config *cfg, const vd_cusum *c, vibid_change_reference *ref,
                      char *err, size_t cap)
{
    FILE *f = fopen(path, "re");
    if (!f) {
        if (errno == ENOENT)
            return 0;
        snprintf(err, cap, "%s: cannot read: %s", path, strerror(errno));
        return -1;
    }
    unsigned char have[VD_MAX_PARAMS][REF_SLOTS]; /* 16 KB: the stack of any thread has it */
    memset(have, 0, sizeof have);
    double n_terms[VD_MAX_PARAMS] = {0};
    int format = 0;
    memset(ref, 0, c->n * sizeof *ref);
    bool have_key = false, have_format = false;
    char line[1024];
    int ln = 0, rc = 0;
    const uint64_t want = vd_reference_key(cfg, c);
    while (rc == 0 && fgets(line, sizeof line, f)) {
        ln++;
        size_t n = strlen(line);
        if (n == sizeof line - 1 && line[n - 1] != '\n') {
            snprintf(err, cap, "%s:%d: line longer than %zu characters", path, ln, sizeof line - 2);
            rc = -1;
            break;
        }
        while (n > 0 && (line[n - 1] == '\n' || line[n - 1] == '\r'))
            line[--n] = '\0';
        if (n == 0 || line[0] == '#')
            continue;
        char *eq = strchr(line, '=');
        if (!eq) {
            snprintf(err, cap, "%s:%d: expected key=value, got '%.80s'", path, ln, line);
            rc = -1;
            break;
        }
        *eq = '\0';
        const char *key = line, *val = eq + 1;
        if (!strcmp(key, "format")) {
            if (strcmp(val, "1") && strcmp(val, "2")) {
                snprintf(err, cap, "%s:%d: format %.20s, this vibidd reads formats 1 and 2", path, ln, val);
                rc = -1;
            }
            format = val[0] - '0';
            have_format = true;
        } else if (!strcmp(key, "key")) {
            char *end;
            errno = 0;
            unsigned long long k = strtoull(val, &end, 16);
            if (errno || end == val || *end) {
                snprintf(err, cap, "%s:%d: key '%.40s' is not 16 hex digits", path, ln, val);
                rc = -1;
            } else if (k != want) {
                snprintf(err, cap,
                         "%s: the saved alarm reference has key %016llx, this stand and estimator setting %016llx: "
                         "it was learned for another stand, estimator setting or set of alarmed parameters; "
                         "keep it (another alarms.reference_file) or replace it with vibidd --reference learn "
                         "(or remove it with --reference forget)",
                         path, k, (unsigned long long)want);
                rc = -1;
            }
            have_key = true;
        } else if (!strcmp(key, "stand") || !strcmp(key, "learned_index") || !strcmp(key, "learned_time_s")) {
            continue; /* for the reader; the key decides */
        } else {
            size_t i;
            const char *fld;
            char *end;
            double v = strtod(val, &end);
            if (field_of(cfg, c, key, &i, &fld) || end == val || *end) {
                snprintf(err, cap, "%s:%d: '%.80s=%.40s' is not a value of an alarmed parameter", path, ln, key, val);
                rc = -1;
                break;
            }
            unsigned slot;
            double *dst = format ? ref_field(&ref[i], format, cfg->n_covariates, &n_terms[i], fld, &slot) : NULL;
            if (!dst) {
                snprintf(err, cap,
                         "%s:%d: unknown field '%.40s' (after format=: mean, block_sd, n_mean, n_sd; with %zu "
                         "covariates centre_J, low_J, high_J, origin_J, n_terms, slope_T, term_mean_T, "
                         "gram_inv_T_L)",
                         path, ln, fld, cfg->n_covariates);
                rc = -1;
                break;
            }
            if (have[i][slot]) {
                snprintf(err, cap, "%s:%d: '%.80s' given twice", path, ln, key);
                rc = -1;
                break;
            }
            *dst = v;
            have[i][slot] = 1;
        }
    }
    if (rc == 0 && ferror(f)) {
        snprintf(err, cap, "%s: read error: %s", path, strerror(errno));
        rc = -1;
    }
    fclose(f);
    if (rc)
        return -1;
    if (!have_format || !have_key) {
        snprintf(err, cap, "%s: not a vibidd alarm reference (no format= or key= line)", path);
        return -1;
    }
    const size_t q = cfg->n_covariates;
    for (size_t i = 0; i < c->n; i++) {
        vibid_change_reference *r = &ref[i];
        size_t T = q;
        if (format == 2 && q) {
            const double nt = n_terms[i];
            if (!have[i][20] || !(nt == (double)q || nt == (double)(q + q * (q + 1) / 2))) {
                snprintf(err, cap, "%s: parameter %s: n_terms %g (need %zu or %zu for %zu covariates)", path,
                         vd_param_name(cfg, c->param[i]), nt, q, q + q * (q + 1) / 2, q);
                return -1;
            }
            T = (size_t)nt;
            r->n_terms = T;
            /* gram_inv was read into a 14 x 14 layout: packed to T x T */
            for (size_t a = 0; a < T; a++)
                for (size_t l = 0; l < T; l++)
                    r->gram_inv[a * T + l] = r->gram_inv[a * VIBID_CHANGE_MAX_TERMS + l];
        }
        /* the slots a complete reference has */
        bool complete = true;
        for (unsigned b = 0; b < 4; b++)
            complete = complete && have[i][b];
        for (size_t j = 0; j < q; j++)
            for (unsigned b = 0; b < 4; b++)
                complete = complete && have[i][4 + 4 * j + b];
        for (size_t t = 0; format == 2 && t < T; t++)
            complete = complete && have[i][21 + 2 * t] && have[i][22 + 2 * t];
        for (size_t a = 0; a < T; a++)
            for (size_t l = 0; l < T; l++)
                complete = complete && have[i][49 + 14 * a + l];
        if (!complete) {
            snprintf(err, cap, "%s: parameter %s incomplete (needs mean, block_sd, n_mean, n_sd%s)", path,
                     vd_param_name(cfg, c->param[i]),
                     q ? (format == 1 ? " and per covariate slope, centre, low, high, gram_inv"
                                      : " and per covariate centre, low, high, origin, n_terms, per term slope, "
                                        "term_mean, gram_inv")
                       : "");
            return -1;
        }
    }
    return 1;
}
