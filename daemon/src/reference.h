/* reference.h: the change test's reference on disk (alarms.reference_file), so that a
 * restart after damage does not learn the damaged machine as normal.
 *
 * The file (text, one key=value a line, '#' comments):
 *     # vibidd alarm reference: replaced only by vibidd --reference learn|forget
 *     format=1
 *     stand=<the stand's name>
 *     key=<16 hex digits>
 *     learned_index=<sample index of the row that completed it, in the run that learned it>
 *     learned_time_s=<that row's time, s since the epoch>
 *     <parameter>.mean=<m>            one group per alarmed parameter, %.17g
 *     <parameter>.block_sd=<sigma_b>
 *     <parameter>.n_mean=<N or inf>
 *     <parameter>.n_sd=<N or inf>
 * The key is a 64-bit FNV-1a hash of what the block estimates' statistics depend on: the
 * stand's name, sample rate and parameters (names, in order), the estimator settings
 * (method, forgetting, decimation, pre-filter, IV lag, difference order) and the alarmed
 * parameters. A file whose key differs belongs to another stand or setting: vibidd refuses to
 * start (exit 2) rather than replace it, naming both keys and the commands.
 *
 * Writing: a .tmp file, fsync, rename over the file, fsync of the directory: a crash leaves
 * the old file or the new one, never half of one.
 */
#ifndef VIBIDD_REFERENCE_H
#define VIBIDD_REFERENCE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include <vibid/change.h>

#include "alarm.h"
#include "config.h"

/* The key of cfg's stand and estimator settings with the alarmed parameters of c. */
uint64_t vd_reference_key(const vd_config *cfg, const vd_cusum *c);

/* Writes c's reference (complete) to path. 0, or -1 with err. */
int vd_reference_save(const char *path, const vd_config *cfg, const vd_cusum *c, uint64_t learned_index,
                      double learned_time_s, char *err, size_t cap);

/* Reads path into ref[0 .. c->n) (the alarmed parameters' order). 1 read; 0 no such file;
 * -1 with err (unreadable, malformed: file:line and what; another key; a parameter missing). */
int vd_reference_load(const char *path, const vd_config *cfg, const vd_cusum *c, vibid_change_reference *ref,
                      char *err, size_t cap);

#endif
