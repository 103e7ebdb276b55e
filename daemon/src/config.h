/* config.h: vibidd's configuration: one libconfig file, read once, checked against
 * explicit ranges, read afterwards only through this struct (chrony's discipline).
 *
 * Every error names file, line and field, e.g.
 *   vibidd.cfg:23: estimator.forgetting: 1.5 outside [0.9, 1]
 * The reference of every directive (type, range, default) is the table in config.c
 * and docs/vibidd.md; `vibidd -c FILE --check` prints the effective configuration
 * with every default filled in (vd_config_print), in the file's own syntax, so that
 * the printout is itself a valid configuration.
 */
#ifndef VIBIDD_CONFIG_H
#define VIBIDD_CONFIG_H

#include <stdbool.h>
#include <stddef.h>
#include <stdio.h>

#include <vibid/cfgread.h>
#include <vibid/identify.h>
#include <vibid/stand_file.h>
#include <vibid_drivers/channel_map.h>
#include <vibid_drivers/dbc.h>
#include <vibid_drivers/register_map.h>
#include <vibid_drivers/source_modbus.h>

#define VD_PATH_MAX 1024
#define VD_MAX_PARAMS 64
#define VD_MAX_COVARIATES 4 /* = VIBID_CHANGE_MAX_COVARIATES (vibid/change.h) */

/* The configuration reader's error (vibid/cfgread.h): file, line (0 if not known), field
 * (setting path, "" for syntax errors), message, and text "file:line: field: message",
 * ready to print. */
typedef vibid_cfg_error vd_config_error;

typedef enum vd_source_kind { VD_SRC_SOCKETCAN = 0, VD_SRC_MODBUS = 1, VD_SRC_REPLAY = 2 } vd_source_kind;
typedef enum vd_record_format { VD_REC_CSV = 0, VD_REC_CANDUMP = 1 } vd_record_format;

/* The alarms' test (docs/vibidd.md, alarms): the change test of vibid/change.h with a
 * stated false-alarm rate, or the rule z > threshold held for `hold` seconds. */
typedef enum vd_alarm_test { VD_ALARM_CUSUM = 0, VD_ALARM_THRESHOLD = 1 } vd_alarm_test;

/* Per-parameter alarm settings (after defaults). */
typedef struct vd_alarm_param {
    char name[64];
    bool enabled;
    bool has_baseline;   /* baseline value given (else learned) */
    double baseline;
} vd_alarm_param;

/* The output-only configuration (an `oma` group instead of `stand`; docs/vibidd.md
 * "Output-only tracking", oma_track.h): the modes of the response channels tracked by
 * SSI-cov (vibid/oma.h) over a sliding window. Its "parameters" (n_params = 2 x modes, the
 * names in param_name) are f<j>_hz and zeta<j> of the tracked modes j = 1 .. modes: the
 * tracks, outputs and alarms treat them as a stand's parameters. */
#define VD_OMA_MAX_MODES (VD_MAX_PARAMS / 2)
typedef struct vd_oma_config {
    bool on;
    char name[64];               /* the machine's name (tags, topics, the reference file) */
    size_t n_modes;              /* modes tracked, 1 .. VD_OMA_MAX_MODES */
    double nominal_hz[VD_OMA_MAX_MODES]; /* their expected frequencies, Hz; 0 = the lowest modes
                                            of the first identification */
    size_t n_refs;               /* reference channels (0 = all) ... */
    size_t refs[VIBID_DRV_MAX_CHANNELS]; /* ... as indices of the response channels */
    double window_s, every_s, block_s; /* the window, the period of identification, a block */
    unsigned block_rows, max_order;    /* vibid_oma_config's (max_order 0: automatic) */
    double max_damping;          /* poles above are not physical (vibid_oma_config) */
    double match_freq, match_mac;/* a mode of a window continues a tracked mode when its frequency
                                    is within match_freq (relative) and its shape's MAC >= match_mac */
    char param_name[VD_MAX_PARAMS][16];
    /* oma.stand: a stand without inputs that names the nodes of the response channels (its
     * measured channels, by name); "" / NULL: none */
    char stand_file[VD_PATH_MAX];
    vibid_stand *stand;          /* owned */
} vd_oma_config;

/* The settings of the network outputs (output.h), one struct each: the output reads its own
 * struct and nothing else of them; config.c fills them from the output's group. */

/* outputs.tracks, outputs.influx (file, UDP, tags), outputs.record, outputs.status: the
 * file outputs (writers.h, docs/vibidd.md "Outputs"); a path "" = that part is off */
typedef struct vd_files_config {
    char tracks_path[VD_PATH_MAX];
    double flush_interval_s;     /* outputs.tracks.flush_interval: every output's flush period, s */
    bool fsync_on_flush;
    char influx_path[VD_PATH_MAX];
    char influx_udp[128];        /* "HOST:PORT"; "" = off */
    char influx_measurement[64];
    char influx_site[64], influx_stand[64]; /* tags; influx_site "" = no site tag, influx_stand
                                               "" = the stand's name */
    char record_path[VD_PATH_MAX];
    vd_record_format record_format;
    char status_path[VD_PATH_MAX];
    double status_interval_s;    /* outputs.status.interval: the status snapshot's period, s */
} vd_files_config;

/* outputs.prometheus (metrics.h, docs/vibidd.md "Prometheus metrics") */
typedef struct vd_prometheus_config {
    char listen[128];            /* "HOST:PORT"; "" = off */
} vd_prometheus_config;

/* outputs.mqtt (mqtt.h, docs/vibidd.md "MQTT"); url "" = off */
typedef struct vd_mqtt_config {
    char url[256];
    bool tls;                    /* mqtts:// */
    char host[200];              /* from the URL (an IPv6 literal without its brackets) */
    int port;
    char site[64], stand[64];    /* topic levels; stand "" = the stand's name */
    char prefix[128];            /* topic_prefix, e.g. "vibid/v1" */
    char client_id[128];         /* "" = "vibidd-<site>-<stand>" */
    char username[128];
    char password_file[VD_PATH_MAX], ca_file[VD_PATH_MAX], cert_file[VD_PATH_MAX], key_file[VD_PATH_MAX];
    int qos;                     /* 1 or 2 */
    unsigned queue_size;         /* messages between the estimation thread and the publisher */
    int format;                  /* 0 json, 1 line (InfluxDB line protocol) */
    int keepalive;               /* s */
    int protocol;                /* 5 (MQTT 5) or 4 (MQTT 3.1.1) */
    double drain_timeout_s;      /* at the end: longest wait for the queue to reach the broker */
} vd_mqtt_config;

/* outputs.influx.http (influx_http.h, docs/vibidd.md "InfluxDB over HTTP"); url "" = off */
typedef struct vd_influx_http_config {
    char url[256];               /* http(s)://HOST[:PORT][/PATH], no trailing slash */
    int api;                     /* 1: POST /write?db=&rp= (InfluxDB 1.x, basic auth);
                                    2: POST /api/v2/write?org=&bucket= (token) */
    char database[128], rp[128]; /* api 1 */
    char org[128], bucket[128];  /* api 2 */
    char username[128];
    char password_file[VD_PATH_MAX], token_file[VD_PATH_MAX], ca_file[VD_PATH_MAX];
    unsigned batch_lines;        /* lines per request at most */
    double batch_interval_s;     /* a line waits at most this long for its batch */
    unsigned buffer_mib;         /* lines waiting for the server (the retry buffer) */
    double timeout_s;            /* one request, connection included */
    double drain_timeout_s;      /* at the end: longest wait for the buffer to reach the server */
} vd_influx_http_config;

typedef struct vd_config {
    char path[VD_PATH_MAX];      /* the configuration file */
    char dir[VD_PATH_MAX];       /* its directory: relative paths are relative to it */

    /* stand (NULL in an output-only configuration: oma.on) */
    char stand_file[VD_PATH_MAX];/* "" when inline */
    vibid_stand *stand;          /* owned */
    vd_oma_config oma;           /* the output-only configuration (oma.on), instead of a stand */
    double sample_rate;          /* from the stand (or oma.sample_rate), Hz */
    size_t n_params, n_channels, n_modes;

    /* source */
    vd_source_kind source_kind;
    int source_line;
    char dbc_file[VD_PATH_MAX];  /* socketcan / candump replay */
    vibid_dbc *dbc;              /* owned */
    char chanmap_file[VD_PATH_MAX]; /* "" when inline */
    vibid_chanmap chanmap;
    size_t model_to_chan[VIBID_DRV_MAX_CHANNELS]; /* model channel i -> chanmap index (output-only:
                                                     response channel i) */
    double chan_scale[VIBID_DRV_MAX_CHANNELS];    /* chanmap channel k: its unit -> the stand's units (> 0) */
    double model_scale[VIBID_DRV_MAX_CHANNELS];   /* model channel i: chan_scale of its chanmap channel */
    /* covariates: the channel map's `covariate` channels in map order (operating conditions
     * the change test compensates for; written in the tracks) */
    size_t n_covariates;                          /* 0 .. VD_MAX_COVARIATES */
    size_t cov_chan[VD_MAX_COVARIATES];           /* covariate j -> chanmap index */
    char cov_unit[VD_MAX_COVARIATES][32];         /* its unit label (map, else DBC; "" none) */
    /* socketcan */
    char iface[32];
    int rcvbuf_bytes;
    bool hw_timestamps;
    unsigned can_batch;
    /* modbus */
    char url[256];
    vibid_modbus_transport transport;
    char host[128];
    int port;
    char device[256];
    int baud;
    char parity;
    int unit_id;
    vibid_modbus_mode modbus_mode;
    char regmap_file[VD_PATH_MAX];
    vibid_regmap *regmap;        /* owned */
    double poll_period_s;
    unsigned fifo_base;
    double response_timeout_s, backoff_initial_s, backoff_max_s;
    unsigned max_timeouts;
    /* replay */
    char replay_file[VD_PATH_MAX];
    int replay_format;           /* vibid_replay_format */
    bool paced;
    double speed;

    /* acquisition */
    unsigned ring_size;
    unsigned read_batch;
    int read_timeout_ms;
    int rt_priority;             /* 0 = SCHED_OTHER */
    bool lock_memory;
    unsigned handoff_spin_us;    /* estimation thread busy-waits this long for a record before
                                    sleeping on the eventfd; 0 = sleep at once */

    /* estimator */
    vibid_estimator method;           /* default VIBID_ESTIMATOR_AUTO */
    double forgetting, prefilter_hz, rls_alpha;   /* prefilter_hz < 0: automatic */
    unsigned iv_lag;                  /* 0: automatic */
    unsigned difference_order;        /* 0: automatic, else 2 or 4 */
    unsigned decimation;
    unsigned warmup_samples;
    double outlier_threshold;         /* K of vibid/outlier.h; 0 = no outlier test */
    double refine_every_s;            /* output-error refinement period, s of sample time; 0 = off */
    double refine_window_s;           /* the refinement's window, s */
    bool refine_explicit;             /* refine_every given in the file */
    char refine_why[512];             /* why refinement is on or off (--check, the log) */
    bool has_start;                   /* estimator.start_values given (RLS only) */
    double start_theta[VD_MAX_PARAMS];/* RLS start values, stand parameter order; the stand's
                                         nominal value for a parameter the list leaves out */

    /* outputs: each output reads its settings from its groups (output.h, its load) */
    vd_files_config files;           /* outputs.tracks, .influx, .record, .status (writers.c) */
    vd_prometheus_config prometheus; /* outputs.prometheus (metrics.c) */
    vd_mqtt_config mqtt;             /* outputs.mqtt (mqtt.c) */
    vd_influx_http_config influx_http; /* outputs.influx.http (influx_http.c) */

    /* alarms */
    bool alarms_enabled;
    vd_alarm_test alarm_test;        /* the change test (default) or the old threshold rule */
    double alarm_false_per_year;     /* cusum: false alarms a year, all parameters together */
    double alarm_horizon_s;          /* cusum: horizon of the minimum detectable change */
    double alarm_detection_probability; /* cusum: of the minimum detectable change */
    double alarm_threshold, alarm_min_relative, alarm_hold_s; /* threshold, hold: the threshold rule */
    double learn_start_s, learn_duration_s;
    char alarm_reference_file[VD_PATH_MAX]; /* cusum: the reference kept across restarts
                                               (reference.h); "" = learned at every start */
    vd_alarm_param alarm_param[VD_MAX_PARAMS];

    /* log */
    int log_level;
    double log_status_interval_s;
} vd_config;

/* The name of parameter k (< n_params): the stand's unknown, or the output-only
 * configuration's f<j>_hz / zeta<j>. */
const char *vd_param_name(const vd_config *cfg, size_t k);
/* The stand's name, or the output-only configuration's oma.name. */
const char *vd_stand_name(const vd_config *cfg);

/* Reads and checks the file. Returns 0, or -1 with *err filled. On success the
 * config owns the stand, DBC and register map: release with vd_config_free. */
/* The directory part of path into dir (n bytes): "." without a slash, "/" for a file in
 * the root. */
void vd_path_dir(const char *path, char *dir, size_t n);
int vd_config_load(const char *path, vd_config *cfg, vd_config_error *err);
void vd_config_free(vd_config *cfg);
/* Outputs must not destroy each other or the inputs: any two of the output paths (tracks,
 * influx file, record, status) that are the same file, or an output that is an input (the
 * configuration, stand, DBC, channel map, register map, or the replayed capture: replay,
 * or NULL for the configured one) is an error naming both. Same file: the same device and
 * inode for existing files, the same canonical directory and name otherwise (so
 * "./a.csv", "a.csv" and a symlink to it all match). Returns 0, or -1 with msg filled. */
/* A secret (password, token) from the first line of the file path, for the setting named
 * setting (e.g. "outputs.mqtt.password_file"); warns when every user may read the file. 0, or
 * -1 with err naming the setting and the file (unreadable, empty, longer than cap - 2). */
/* The file path, named by setting, can be opened for reading ("" is no file: 0). 0, or -1
 * with err naming the setting, the file and errno (vibidd --check of TLS and CA files). */
int vd_check_readable_file(const char *setting, const char *path, char *err, size_t cap);
int vd_read_secret_file(const char *setting, const char *path, char *out, size_t cap, char *err, size_t ecap);
int vd_config_check_paths(const vd_config *cfg, const char *replay, char *msg, size_t n);
/* The same for the output paths of the outputs named in outputs (NULL-terminated names of
 * outputs or their parts, output.h: "tracks", "influx", "record", "status"; NULL: all). */
int vd_config_check_paths_for(const vd_config *cfg, const char *replay, const char *const *outputs, char *msg,
                              size_t n);
/* Prints the effective configuration (valid libconfig syntax, defaults filled in). */
void vd_config_print(const vd_config *cfg, FILE *out);
const char *vd_source_kind_name(vd_source_kind k);
const char *vd_estimator_name(vibid_estimator e);

#endif
