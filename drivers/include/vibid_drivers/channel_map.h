/* vibid_drivers/channel_map.h: ties bus signals, Modbus registers or CSV columns to the
 * stand's channels. Independent of libvibid's model API: a channel is named, belongs
 * to a node (0-based index in the stand description) and measures one quantity.
 *
 * libconfig syntax (a group, e.g. the daemon's `source` section or a file's root):
 *   channels = (
 *     { name = "F1"; quantity = "force";        node = 0; unit = "N";   signal = "Force1"; },
 *     { name = "x1"; quantity = "displacement"; node = 0; unit = "m";   signal = "Pos1"; message = "Sample_A"; },
 *     { name = "x2"; quantity = "displacement"; node = 1; unit = "m";   register = "x2"; },
 *     { name = "s";  quantity = "base_displacement"; unit = "mm"; column = "xb"; }
 *   );
 *   counter = "SampleCounter";   # optional: DBC signal numbering the samples
 *   trigger = "Sample_A";        # optional: message that starts a sample (if no counter)
 *   time_column = "t";           # optional: CSV column holding time in seconds
 * quantity: displacement | velocity | acceleration of a node (outputs y); force or input
 * (a force input u, `input` when it is in other units than a force, e.g. a drive voltage
 * that the stand's input gain converts); base_displacement | base_velocity |
 * base_acceleration (the base's motion; no node); covariate (an operating condition such as
 * a temperature, a speed or a load; no node; any unit label). node: 0-based index of the node in the
 * stand, required except for the base (omitted, or 0 as earlier maps wrote). unit:
 * optional, one of vibid/units.h for the quantity's dimension (any label for `input` and
 * `covariate`);
 * the program checking the map against the stand (vibidd's configuration) converts it
 * to the stand's units. Exactly one of signal / register / column per channel (message
 * only narrows a signal name that several messages share). Any other key is an error. At
 * most VIBID_DRV_MAX_CHANNELS channels; names unique.
 */
#ifndef VIBID_DRIVERS_CHANNEL_MAP_H
#define VIBID_DRIVERS_CHANNEL_MAP_H

#include <stdbool.h>
#include <stddef.h>

#include <libconfig.h>
#include <vibid/cfgread.h>
#include <vibid_drivers/status.h>

#ifdef __cplusplus
extern "C" {
#endif

#define VIBID_DRV_MAX_CHANNELS 32
#define VIBID_CHAN_NAME_LEN 128

typedef enum vibid_quantity {
    VIBID_Q_DISPLACEMENT = 0,
    VIBID_Q_VELOCITY = 1,
    VIBID_Q_ACCELERATION = 2,
    VIBID_Q_FORCE = 3,
    VIBID_Q_BASE_DISPLACEMENT = 4,
    VIBID_Q_BASE_VELOCITY = 5,
    VIBID_Q_BASE_ACCELERATION = 6,
    VIBID_Q_INPUT = 7, /* a force input in its own units (the stand's gain converts it) */
    VIBID_Q_COVARIATE = 8 /* an operating condition (temperature, speed, load; any unit label):
                             neither input nor output; vibidd's change test compensates for it */
} vibid_quantity;

typedef enum vibid_chan_source { VIBID_CHAN_SIGNAL, VIBID_CHAN_REGISTER, VIBID_CHAN_COLUMN } vibid_chan_source;

typedef struct vibid_channel {
    char name[VIBID_CHAN_NAME_LEN];
    vibid_quantity quantity;
    bool is_input;             /* force / input / base_*: an input of the stand; covariate: neither;
                                  else an output y_k */
    int node;                  /* >= 0; -1 for the base quantities */
    char unit[32];             /* as written, "" when not given */
    vibid_chan_source source;
    char ref[VIBID_CHAN_NAME_LEN];     /* signal, register or column name */
    char message[VIBID_CHAN_NAME_LEN]; /* optional message for a signal; "" = any */
    unsigned line;
} vibid_channel;

typedef struct vibid_chanmap {
    size_t n;
    vibid_channel ch[VIBID_DRV_MAX_CHANNELS];
    char counter[VIBID_CHAN_NAME_LEN];     /* "" when not given */
    char trigger[VIBID_CHAN_NAME_LEN];     /* "" when not given */
    char time_column[VIBID_CHAN_NAME_LEN]; /* "" when not given */
} vibid_chanmap;

/* Reads the channel map held by `group` (its members channels, counter, trigger,
 * time_column; the group's other members are the caller's to check) with the
 * configuration reader r (vibid/cfgread.h); path is the group's setting path ("" for a
 * file's root, "source" for vibidd's section) and prefixes the fields in messages, e.g.
 * "map.cfg:7: channels.[1].quantity: 'forse' is not one of ...". On failure the map is
 * partly filled and r->err holds the reason. */
vibid_drv_status vibid_chanmap_read(const vibid_cfg_reader *r, const config_setting_t *group,
                                    const char *path, vibid_chanmap *map);
/* Reads a channel-map file: a root holding `channels` and optionally counter, trigger,
 * time_column (any other key is an error). err gets file, line, field and reason. */
vibid_drv_status vibid_chanmap_read_file(const char *path, vibid_chanmap *map, vibid_cfg_error *err);
/* The same with the drivers' error holder (err->text = the reader's text). */
vibid_drv_status vibid_chanmap_load(const char *path, vibid_chanmap *map, vibid_drv_error *err);
const char *vibid_quantity_name(vibid_quantity q);
/* base_displacement, base_velocity, base_acceleration */
bool vibid_quantity_is_base(vibid_quantity q);

#ifdef __cplusplus
}
#endif
#endif
