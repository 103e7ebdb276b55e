/* example_common.c: see example_common.h. */
#include "example_common.h"

#include <libconfig.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

static int ok(vibid_status s, const char *what) {
    if (s != VIBID_OK) {
        fprintf(stderr, "%s: %s (%s)\n", what, vibid_strerror(s), vibid_last_error());
        return 0;
    }
    return 1;
}

vibid_stand *example_load_stand(const char *path, int disc_override) {
    vibid_stand_error err;
    vibid_stand *st = vibid_stand_load(path, &err);
    if (!st) {
        fprintf(stderr, "%s\n", err.text);
        return NULL;
    }
    vibid_model_dims dims;
    if (disc_override < 0 || !ok(vibid_model_get_dims(vibid_stand_model(st), &dims), "model dims") ||
        (int)dims.discretization == disc_override)
        return st;
    vibid_stand_destroy(st);
    /* Same file, discretization field replaced in memory, same loader. */
    config_t cfg;
    st = NULL;
    if (vibid_cfg_read_file(&cfg, path, &err)) { /* the one reader: its limits, its messages */
        fprintf(stderr, "%s\n", err.text);
    } else {
        config_setting_t *g = config_lookup(&cfg, "stand");
        config_setting_t *d = g ? config_setting_get_member(g, "discretization") : NULL;
        if (g && !d) d = config_setting_add(g, "discretization", CONFIG_TYPE_STRING);
        if (!d || !config_setting_set_string(d, disc_override == VIBID_DISC_ZOH ? "zoh" : "central_difference"))
            fprintf(stderr, "%s: cannot set stand.discretization\n", path);
        else if (!(st = vibid_stand_from_setting(g, path, &err)))
            fprintf(stderr, "%s\n", err.text);
    }
    config_destroy(&cfg);
    return st;
}

int example_parse_args(int argc, char **argv, const char *default_stand, const char **stand_path,
                       const char **outdir) {
    *stand_path = default_stand;
    *outdir = ".";
    int positional = 0;
    for (int i = 1; i < argc; ++i) {
        if (!strcmp(argv[i], "--stand") && i + 1 < argc) {
            *stand_path = argv[++i];
        } else if (argv[i][0] == '-' || positional++) {
            fprintf(stderr, "usage: %s [--stand FILE] [output-directory]\n  default stand file: %s\n", argv[0],
                    default_stand);
            return -1;
        } else {
            *outdir = argv[i];
        }
    }
    return 0;
}

const size_t example_checkpoints[] = {10, 20, 50, 100, 200, 500, 1000, 2000, 5000, 10000, 20000};
const size_t example_n_checkpoints = sizeof example_checkpoints / sizeof example_checkpoints[0];

const char *example_estimator_label(vibid_estimator e) {
    return e == VIBID_ESTIMATOR_LS     ? "batch LS"
           : e == VIBID_ESTIMATOR_IV   ? "batch IV"
           : e == VIBID_ESTIMATOR_AUTO ? "automatic estimator (the default: IV, five-point stencils, pre-filter and lag chosen)"
                                       : "RLS";
}

FILE *example_open_tracks(const char *outdir, const char *tag, const vibid_model *model, char *path, size_t cap) {
    snprintf(path, cap, "%s/%s_tracks.csv", outdir, tag);
    FILE *csv = fopen(path, "w");
    if (!csv) {
        perror(path);
        return NULL;
    }
    vibid_model_dims dims;
    if (!ok(vibid_model_get_dims(model, &dims), "model dims")) return csv;
    fprintf(csv, "case,N");
    for (size_t i = 0; i < dims.n_params; ++i) {
        vibid_param_info pi;
        if (ok(vibid_model_param_info(model, i, &pi), "param info")) fprintf(csv, ",%s,%s_se", pi.name, pi.name);
    }
    fprintf(csv, "\n");
    return csv;
}

void example_plot(const char *outdir, const char *tag, const vibid_model *model, const double *truth) {
    vibid_model_dims dims;
    if (!ok(vibid_model_get_dims(model, &dims), "model dims")) return;
    char params[512] = "", truths[512] = "";
    size_t lp = 0, lt = 0;
    for (size_t i = 0; i < dims.n_params; ++i) {
        vibid_param_info pi;
        if (!ok(vibid_model_param_info(model, i, &pi), "param info")) return;
        lp += (size_t)snprintf(params + lp, sizeof params - lp, "%s%s", i ? " " : "", pi.name);
        lt += (size_t)snprintf(truths + lt, sizeof truths - lt, "%s%.10g", i ? " " : "", truth[i]);
        if (lp >= sizeof params || lt >= sizeof truths) return;
    }
    char cmd[4096];
    fflush(stdout); /* keep our table ahead of gnuplot's message */
    snprintf(cmd, sizeof cmd,
             "command -v gnuplot >/dev/null 2>&1 && gnuplot -e \"csv='%s/%s_tracks.csv'; png='%s/%s_tracks.png'; "
             "params='%s'; truths='%s'\" '%s' && echo 'plot written to %s/%s_tracks.png'",
             outdir, tag, outdir, tag, params, truths, VIBID_EXAMPLES_DIR "/plot_tracks.gp", outdir, tag);
    if (system(cmd) != 0) printf("(gnuplot not run: no plot)\n");
}

int example_run_case(const example_case *c, const vibid_model *model, double h, const double *record,
                     size_t n_samples, const size_t *checkpoints, size_t n_checkpoints, const double *truth, FILE *csv,
                     double *rel_err_out) {
    vibid_ident_config cfg;
    vibid_ident_config_init(&cfg, h);
    cfg.estimator = c->estimator;
    if (c->estimator != VIBID_ESTIMATOR_AUTO) {
        /* The paper's cases as labelled: central differences (1.17), the given pre-filter
         * and lag (3 when not given); the automatic estimator chooses all of them. */
        cfg.prefilter_hz = c->prefilter_hz;
        cfg.difference_order = 2;
        cfg.iv_lag = c->iv_lag ? c->iv_lag : 3;
    }
    vibid_model_dims dims;
    if (!ok(vibid_model_get_dims(model, &dims), "model dims")) return -1;
    if (dims.discretization != c->disc) {
        fprintf(stderr, "case %s: the model's discretization is not the case's\n", c->name);
        return -1;
    }
    const vibid_model *local = model;
    vibid_ident *id = NULL;
    id = vibid_ident_create(local, &cfg);
    if (!id) {
        fprintf(stderr, "case %s: %s\n", c->name, vibid_last_error());
        return -1;
    }
    size_t nc = 0, p = 0;
    vibid_ident_dims(id, &nc, &p);
    double sample[16], theta[8], se[8];
    if (nc > 16 || p > 8) {
        fprintf(stderr, "case %s: %zu channels, %zu unknowns: at most 16 and 8 here\n", c->name, nc, p);
        vibid_ident_destroy(id);
        return -1;
    }
    size_t next = 0;
    int rc = 0;
    printf("  %-22s %7s", c->name, "N");
    for (size_t i = 0; i < p; ++i) {
        vibid_param_info pi;
        vibid_model_param_info(local, i, &pi);
        printf(" %14s %9s", pi.name, "err%");
    }
    printf("\n");
    for (size_t k = 0; k < n_samples && next < n_checkpoints; ++k) {
        for (size_t ch = 0; ch < nc; ++ch) sample[ch] = record[k + ch * n_samples];
        if (!ok(vibid_ident_push(id, sample), "push")) {
            rc = -1;
            break;
        }
        if (k + 1 == checkpoints[next]) {
            vibid_status s = vibid_ident_estimate(id, theta, se, NULL);
            printf("  %-22s %7zu", c->name, checkpoints[next]);
            if (s == VIBID_OK) {
                for (size_t i = 0; i < p; ++i)
                    printf(" %14.6g %+9.3f", theta[i], 100.0 * (theta[i] - truth[i]) / truth[i]);
                if (csv) {
                    fprintf(csv, "%s,%zu", c->name, checkpoints[next]);
                    for (size_t i = 0; i < p; ++i) fprintf(csv, ",%.10g,%.6g", theta[i], se[i]);
                    fprintf(csv, "\n");
                }
                if (rel_err_out && next + 1 == n_checkpoints)
                    for (size_t i = 0; i < p; ++i) rel_err_out[i] = fabs(theta[i] - truth[i]) / fabs(truth[i]);
            } else {
                printf("  (%s: %s)", vibid_strerror(s), vibid_last_error());
            }
            printf("\n");
            ++next;
        }
    }
    vibid_ident_destroy(id);
    return rc;
}
