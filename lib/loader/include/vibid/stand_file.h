/* vibid/stand_file.h: the stand-file loader shared by every vibid program (examples,
 * vibid-sim, vibidd). It reads a stand description in libconfig syntax (format:
 * docs/stand-file.md), builds the vibid_model through the public C API only, and keeps
 * what the programs need beside the model: the stand's name and sample rate, the
 * acquisition channel name of every model channel, and the true values of the unknowns
 * and of the disturbances' intensities (for simulation).
 *
 * libvibid itself does no file I/O; this is the static library vibid_stand (C11,
 * links libconfig and libvibid).
 *
 * Errors name file, line and field (the configuration reader, vibid/cfgread.h):
 * "stand.cfg:14: stand.elements.[1].kind: 'sprung' is not one of spring, damper,
 * cubic_spring".
 */
#ifndef VIBID_STAND_FILE_H
#define VIBID_STAND_FILE_H

#include <stddef.h>
#include <vibid/cfgread.h>
#include <vibid/model.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct vibid_stand vibid_stand;

/* Where and why loading failed: the configuration reader's error (vibid/cfgread.h):
 * file, line, field (setting path, e.g. "stand.nodes.[0].mass"), message and the text
 * "file:line: field: message", ready to print. */
typedef vibid_cfg_error vibid_stand_error;

/* Loads the group `stand` of the file at path. err may be NULL. NULL on failure. */
vibid_stand *vibid_stand_load(const char *path, vibid_stand_error *err);

/* Same, from a libconfig setting (the stand group of a bigger configuration, e.g. the
 * daemon's). file is used in messages when libconfig does not know it. */
vibid_stand *vibid_stand_from_setting(const config_setting_t *setting, const char *file,
                                      vibid_stand_error *err);

void vibid_stand_destroy(vibid_stand *stand);

/* The finalized model; lives as long as the stand. */
const vibid_model *vibid_stand_model(const vibid_stand *stand);

/* Name of the stand (the `name` field); lives as long as the stand. */
const char *vibid_stand_name(const vibid_stand *stand);

/* Sample rate f_a in Hz (field `sample_rate`), > 0. */
double vibid_stand_sample_rate(const vibid_stand *stand);

/* The stand's length unit (field `length_unit`, default "m"; vibid/units.h), e.g. "mm";
 * lives as long as the stand. Forces are always in N and time in s, so the mass unit is
 * N s^2 per length unit (kg with m, t with mm). Channels that declare other units are
 * converted to these by the program that reads them (vibidd's channel map). */
const char *vibid_stand_length_unit(const vibid_stand *stand);
/* Metres per length unit (1 for "m", 1e-3 for "mm"), > 0. */
double vibid_stand_length_si(const vibid_stand *stand);

/* Node index (vibid_model_find_node) that force input `input` acts on; -1 for a
 * full-matrix stand (its B may spread an input over several coordinates) or an index out
 * of range. */
long vibid_stand_input_node(const vibid_stand *stand, size_t input);

/* Acquisition channel name for model channel i (0 .. n_channels - 1 of
 * vibid_model_get_dims), e.g. the DBC signal or register-map name; NULL if i is out of
 * range. Lives as long as the stand. */
const char *vibid_stand_channel_name(const vibid_stand *stand, size_t channel);

/* Model channel index of an acquisition channel name, or (size_t)-1. */
size_t vibid_stand_find_channel(const vibid_stand *stand, const char *name);

/* True values of the unknowns for simulation (p values, in the model's parameter
 * order): the `true_value` field, or the nominal value where it is absent. Lives as
 * long as the stand. */
const double *vibid_stand_true_values(const vibid_stand *stand);

/* Non-zero if the file gives unknown `index` (model parameter order) an explicit
 * `true_value`: then vibid_stand_true_values holds a truth to compare an estimate with
 * (the Python package's z), not a nominal start value. 0 for full-matrix stands (they have
 * no true_value fields) and for an index out of range. */
int vibid_stand_true_value_given(const vibid_stand *stand, size_t index);

/* True standard deviations of the disturbances for simulation (N, n_disturbances of
 * vibid_model_get_dims, in the model's disturbance order, vibid_model_disturbance_info):
 * the `true_std` field, or `std` where it is absent. 0 where std is unknown and true_std
 * was not given: only a simulator needs it (vibid-sim refuses such a disturbance unless
 * its simulation drives it from an excitation), so loading does not. Lives as long as
 * the stand; never NULL for a loaded stand, also without disturbances. */
const double *vibid_stand_disturbance_true_std(const vibid_stand *stand);

#ifdef __cplusplus
}
#endif
#endif
