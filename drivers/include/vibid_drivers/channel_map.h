/* vibid_drivers/channel_map.h: ties bus signals, Modbus registers or CSV columns to the
 * stand's channels. Independent of libvibid's model API: a channel is named, belongs
 * to a node (0-based index in the stand description) and measures one quantity.
 *
 * libconfig syntax (a group, e.g. the daemon's `source` section or a file's root):
 *   channels = (
 *     { name = "F1"; quantity = "force";        node = 0; unit = "N";   signal = "Force1"; },
 *     { name = "x1"; quantity = "displacement"; node = 0; unit = "m";   signal = "Pos1"; message = "Sample_A"; },
 *     { name = "x2"; quantity = "displacement"; node = 1; unit = "m";   register = "x2"; },
 *     { name = "a0"; quantity = "base_displacement"; node = 0; unit = "m"; column = "xb"; }
 *   );
 *   counter = "SampleCounter";   # optional: DBC signal numbering the samples
 *   trigger = "Sample_A";        # optional: message that starts a sample (if no counter)
 *   time_column = "t";           # optional: CSV column holding time in seconds
 * quantity: displacement | velocity | acceleration (outputs y) | force |
 * base_displacement (inputs u). Exactly one of signal / register / column per channel
 * (message only narrows a signal name that several messages share). At most
 * VIBID_DRV_MAX_CHANNELS channels; names unique.
 */
#ifndef VIBID_DRIVERS_CHANNEL_MAP_H
#define VIBID_DRIVERS_CHANNEL_MAP_H

#include <stdbool.h>
#include <stddef.h>

#include <libconfig.h>
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
    VIBID_Q_BASE_DISPLACEMENT = 4
} vibid_quantity;

typedef enum vibid_chan_source { VIBID_CHAN_SIGNAL, VIBID_CHAN_REGISTER, VIBID_CHAN_COLUMN } vibid_chan_source;

typedef struct vibid_channel {
    char name[VIBID_CHAN_NAME_LEN];
    vibid_quantity quantity;
    bool is_input;             /* force / base_displacement: part of u_k; else y_k */
    int node;                  /* >= 0 */
    char unit[32];
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

/* Fills *map from a group setting holding `channels`. err = "file:line: ...". */
vibid_drv_status vibid_chanmap_from_setting(const config_setting_t *group, const char *file,
                                            vibid_chanmap *map, vibid_drv_error *err);
/* Reads a libconfig file whose root holds `channels` (and optional counter, ...). */
vibid_drv_status vibid_chanmap_load(const char *path, vibid_chanmap *map, vibid_drv_error *err);
const char *vibid_quantity_name(vibid_quantity q);

#ifdef __cplusplus
}
#endif
#endif
