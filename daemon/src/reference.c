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

static const char *param_name(const vd_config *cfg, size_t k)
{
    vibid_param_info pi;
    vibid_model_param_info(vibid_stand_model(cfg->stand), k, &pi);
    return pi.name;
}

uint64_t vd_reference_key(const vd_config *cfg, const vd_cusum *c)
{
    uint64_t h = 0xcbf29ce484222325ull;
    h = fnv_str(h, vibid_stand_name(cfg->stand));
    h = fnv_num(h, cfg->sample_rate);
    for (size_t k = 0; k < cfg->n_params; k++)
        h = fnv_str(h, param_name(cfg, k));
    h = fnv_str(h, vibid_estimator_name(cfg->method));
    h = fnv_num(h, cfg->forgetting);
    h = fnv_num(h, (double)cfg->decimation);
    h = fnv_num(h, cfg->prefilter_hz);
    h = fnv_num(h, (double)cfg->iv_lag);
    h = fnv_num(h, (double)cfg->difference_order);
    for (size_t i = 0; i < c->n; i++)
        h = fnv_str(h, param_name(cfg, c->param[i]));
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
            "format=1\nstand=%s\nkey=%016llx\nlearned_index=%llu\nlearned_time_s=%.6f\n",
            vibid_stand_name(cfg->stand), (unsigned long long)vd_reference_key(cfg, c),
            (unsigned long long)learned_index, learned_time_s);
    for (size_t i = 0; i < c->n; i++) {
        const char *p = param_name(cfg, c->param[i]);
        fprintf(f, "%s.mean=%.17g\n%s.block_sd=%.17g\n%s.n_mean=%.17g\n%s.n_sd=%.17g\n", p, ref[i].mean, p,
                ref[i].block_sd, p, ref[i].n_mean, p, ref[i].n_sd);
        const size_t q = cfg->n_covariates;
        for (size_t j = 0; j < q; j++) {
            fprintf(f, "%s.slope_%zu=%.17g\n%s.centre_%zu=%.17g\n%s.low_%zu=%.17g\n%s.high_%zu=%.17g\n", p, j,
                    ref[i].slope[j], p, j, ref[i].centre[j], p, j, ref[i].low[j], p, j, ref[i].high[j]);
            for (size_t l = 0; l < q; l++)
                fprintf(f, "%s.gram_inv_%zu%zu=%.17g\n", p, j, l, ref[i].gram_inv[j * q + l]);
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

/* A field of a parameter's saved reference: mean, block_sd, n_mean, n_sd (bits 0-3), and per
 * covariate j < q slope_j, centre_j, low_j, high_j (bits 4 + 4 j ..), gram_inv_jl (bits
 * 4 + 4 q + j q + l). NULL for another name. */
static double *ref_field(vibid_change_reference *r, size_t q, const char *fld, unsigned *bit)
{
    static const char *const base[] = {"mean", "block_sd", "n_mean", "n_sd"};
    double *const base_dst[] = {&r->mean, &r->block_sd, &r->n_mean, &r->n_sd};
    for (unsigned b = 0; b < 4; b++)
        if (!strcmp(fld, base[b])) {
            *bit = b;
            return base_dst[b];
        }
    static const char *const per[] = {"slope_", "centre_", "low_", "high_"};
    for (unsigned b = 0; b < 4; b++) {
        size_t n = strlen(per[b]);
        if (!strncmp(fld, per[b], n) && fld[n] >= '0' && (size_t)(fld[n] - '0') < q && !fld[n + 1]) {
            size_t j = (size_t)(fld[n] - '0');
            double *const dst[] = {&r->slope[j], &r->centre[j], &r->low[j], &r->high[j]};
            *bit = (unsigned)(4 + 4 * j + b);
            return dst[b];
        }
    }
    if (!strncmp(fld, "gram_inv_", 9) && fld[9] >= '0' && (size_t)(fld[9] - '0') < q && fld[10] >= '0' &&
        (size_t)(fld[10] - '0') < q && !fld[11]) {
        size_t j = (size_t)(fld[9] - '0'), l = (size_t)(fld[10] - '0');
        *bit = (unsigned)(4 + 4 * q + j * q + l);
        return &r->gram_inv[j * q + l];
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
        const char *p = param_name(cfg, c->param[j]);
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
    uint64_t have[VD_MAX_PARAMS] = {0};
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
            if (strcmp(val, "1")) {
                snprintf(err, cap, "%s:%d: format %.20s, this vibidd reads format 1", path, ln, val);
                rc = -1;
            }
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
            unsigned bit;
            double *dst = ref_field(&ref[i], cfg->n_covariates, fld, &bit);
            if (!dst) {
                snprintf(err, cap,
                         "%s:%d: unknown field '%.40s' (mean, block_sd, n_mean, n_sd; with %zu covariates slope_J, "
                         "centre_J, low_J, high_J, gram_inv_JL)",
                         path, ln, fld, cfg->n_covariates);
                rc = -1;
                break;
            }
            *dst = v;
            have[i] |= 1ull << bit;
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
    const uint64_t all = (1ull << (4 + 4 * q + q * q)) - 1u;
    for (size_t i = 0; i < c->n; i++)
        if (have[i] != all) {
            snprintf(err, cap, "%s: parameter %s incomplete (needs mean, block_sd, n_mean, n_sd%s)", path,
                     param_name(cfg, c->param[i]), q ? " and per covariate slope, centre, low, high, gram_inv" : "");
            return -1;
        }
    return 1;
}
