/* vibid._core's side of vibid.replay, in C because vibidd's headers are C11 (daemon.h and
 * ring.h hold _Atomic members, which C++ cannot include). It runs the sequence of vibidd's
 * main() for `vibidd -c CONFIG [--replay CAPTURE]` through the daemon's own functions
 * (vd_config_load, vd_config_check_paths_for, vd_daemon_init, vd_daemon_run, vd_daemon_fini),
 * with the output "tracks" alone (selected by name, output.h); vibid_drivers.cpp drives it. */
#include "config.h"
#include "daemon.h"
#include "log.h"
#include "rate_check.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "vibid_replay.h"

struct vibid_py_replay {
    vd_config cfg;
    vd_daemon d;
    int cfg_loaded, d_init;
};

int vibid_py_log_level_parse(const char *name) { return vd_log_level_parse(name); }
int vibid_py_rate_mode_parse(const char *name) { return vd_rate_mode_parse(name); }

vibid_py_replay *vibid_py_replay_open(const char *config, const char *capture, const char *tracks, const char *influx,
                                      const char *reference, int rate_mode, char *err, size_t cap)
{
    /* vd_config and vd_daemon are large (main.c keeps them static): on the heap */
    vibid_py_replay *r = calloc(1, sizeof *r);
    if (!r) {
        snprintf(err, cap, "out of memory");
        return NULL;
    }
    vd_config_error cerr;
    if (vd_config_load(config, &r->cfg, &cerr)) {
        snprintf(err, cap, "%s", cerr.text);
        free(r);
        return NULL;
    }
    r->cfg_loaded = 1;
    vd_config *cfg = &r->cfg;
    if (strlen(tracks) >= sizeof cfg->files.tracks_path || (influx && strlen(influx) >= sizeof cfg->files.influx_path) ||
        (reference && strlen(reference) >= sizeof cfg->alarm_reference_file)) {
        snprintf(err, cap, "tracks, influx or reference path too long (at most %zu characters)",
                 sizeof cfg->files.tracks_path - 1);
        vibid_py_replay_close(r);
        return NULL;
    }
    /* Only the tracks (at the caller's path, as vibidd --tracks): the configuration's other
     * outputs are not this call's to write, nor does a Prometheus endpoint or a broker
     * belong to a replay in a Python process; the daemon opens the outputs named here
     * (output.h) and no other. Neither mlockall of the whole interpreter
     * (acquisition.lock_memory) nor SCHED_FIFO (realtime_priority) belongs in a Python
     * process; neither changes a value. */
    static const char *const tracks_only[] = {"tracks", NULL}, *const with_influx[] = {"tracks", "influx", NULL};
    const char *const *outputs = influx ? with_influx : tracks_only;
    snprintf(cfg->files.tracks_path, sizeof cfg->files.tracks_path, "%s", tracks);
    if (influx) { /* the file, not a server: the influx output's file part alone */
        snprintf(cfg->files.influx_path, sizeof cfg->files.influx_path, "%s", influx);
        cfg->files.influx_udp[0] = '\0';
    }
    if (reference)
        snprintf(cfg->alarm_reference_file, sizeof cfg->alarm_reference_file, "%s", reference);
    cfg->lock_memory = false;
    cfg->rt_priority = 0;
    if (vd_config_check_paths_for(cfg, capture, outputs, err, cap)) {
        vibid_py_replay_close(r);
        return NULL;
    }
    if (!capture && cfg->source_kind != VD_SRC_REPLAY) {
        snprintf(err, cap, "%s:%d: source.kind: %s, not replay: give the capture to replay (capture=...)", cfg->path,
                 cfg->source_line, vd_source_kind_name(cfg->source_kind));
        vibid_py_replay_close(r);
        return NULL;
    }
    vd_options opt = {capture, false, 1.0, (vd_rate_mode)rate_mode, outputs};
    r->d_init = 1; /* fini releases what init opened, also when it failed (as main.c) */
    if (vd_daemon_init(&r->d, cfg, &opt, err, cap)) {
        vibid_py_replay_close(r);
        return NULL;
    }
    return r;
}

int vibid_py_replay_run(vibid_py_replay *r) { return vd_daemon_run(&r->d); }

void vibid_py_replay_close(vibid_py_replay *r)
{
    if (!r)
        return;
    if (r->d_init)
        vd_daemon_fini(&r->d);
    if (r->cfg_loaded)
        vd_config_free(&r->cfg);
    free(r);
}

int vibid_py_log_level_set(int level)
{
    vd_log_init_from_env();
    int old = (int)vd_log_get_level();
    vd_log_set_level((vd_log_level)level);
    return old;
}
