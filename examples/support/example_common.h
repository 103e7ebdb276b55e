/* example_common.h: what the paper's example programs share: the two-mass stand of
 * Bild 2 / (4.2), running one identification case against N, and the CSV of the tracks. */
#ifndef EXAMPLE_COMMON_H
#define EXAMPLE_COMMON_H

#include <stdio.h>
#include <vibid/stand_file.h>
#include <vibid/vibid.h>

/* Loads a stand file with the shared loader (vibid_stand, docs/stand-file.md) and, when
 * disc_override >= 0, with its discretization replaced by that vibid_discretization
 * (the stand file names one; a study compares both on the same stand). Errors are
 * printed to stderr with file, line and field. NULL on failure. */
vibid_stand *example_load_stand(const char *path, int disc_override);

/* Sets *stand_path and *outdir from "[--stand FILE] [output-directory]"; defaults: the
 * given in-tree stand file and ".". Returns 0, or -1 after printing the usage. */
int example_parse_args(int argc, char **argv, const char *default_stand, const char **stand_path,
                       const char **outdir);

/* Creates <outdir>/<tag>_tracks.csv (its path in path[cap]) with the header
 * "case,N,<param>,<param>_se,..." from the model's parameter names. NULL (after perror)
 * if it cannot be created. */
FILE *example_open_tracks(const char *outdir, const char *tag, const vibid_model *model, char *path, size_t cap);

/* The sample counts N at which the examples report their estimates. */
extern const size_t example_checkpoints[];
extern const size_t example_n_checkpoints;

/* "batch LS", "batch IV" or "RLS", for the case lines the examples print. */
const char *example_estimator_label(vibid_estimator e);

/* Plots <outdir>/<tag>_tracks.csv to <tag>_tracks.png with examples/plot_tracks.gp if
 * gnuplot is installed (parameter names from the model, truth p values). */
void example_plot(const char *outdir, const char *tag, const vibid_model *model, const double *truth);

typedef struct example_case {
    const char *name;          /* CSV/plot key, e.g. "noisy_cd_ls" */
    vibid_discretization disc;
    vibid_estimator estimator;
    double prefilter_hz;
    size_t iv_lag;
    int noisy;                 /* 1: the record with 1 % noise on every channel */
    int held;                  /* 1: the record with the base held over each interval (ZOH) */
} example_case;

/* Runs one case on a record, with model (its discretization must be c->disc) (n_samples x n_channels, column-major), estimating at each
 * of the n_checkpoints sample counts; prints a table row per checkpoint and appends
 * CSV rows "case,N,<param>,<param>_se..." to csv. truth: true values (p).
 * mean_abs_rel_out (p, may be NULL): |estimate - truth| / |truth| at the last checkpoint. */
int example_run_case(const example_case *c, const vibid_model *model, double h, const double *record,
                     size_t n_samples, const size_t *checkpoints, size_t n_checkpoints, const double *truth, FILE *csv,
                     double *rel_err_out);

#endif
