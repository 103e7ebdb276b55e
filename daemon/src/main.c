/* main.c: vibidd's command line. Modules are initialised in a fixed order and torn
 * down in reverse (daemon.h).
 *
 * Exit status: 0 normal end (signal, end of a replay), 1 run-time failure (source
 * failed, outputs could not be written), 2 usage or configuration error.
 */
#include "config.h"
#include "refine.h"
#include "daemon.h"
#include "log.h"
#include "influx_http.h"
#include "mqtt.h"

#include <errno.h>
#include <getopt.h>
#include <locale.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <vibid/common.h>

static void usage(FILE *o)
{
    fprintf(o,
            "usage: vibidd -c FILE [--check] [--replay CAPTURE [--pace] [--speed X]]\n"
            "              [--tracks F] [--influx F] [--record F] [--status F] [--log-level L]\n"
            "              [--rate-check error|warn|off] [--reference learn|show|forget]\n"
            "  -c, --config FILE   configuration (libconfig; docs/vibidd.md)\n"
            "  --check             validate, print the effective configuration, exit\n"
            "  --replay CAPTURE    run the same pipeline on a capture (candump .log or CSV,\n"
            "                      including vibidd's own raw recordings), as fast as possible\n"
            "  --pace              replay at the recorded pace (--speed X: X times faster)\n"
            "  --tracks F, --influx F, --record F, --status F\n"
            "                      override outputs.*.path (\"\" disables that output)\n"
            "  --log-level L       error, warning, notice, info, debug (overrides log.level)\n"
            "  --rate-check M      the capture's or device's sample rate more than 1 %% off the\n"
            "                      stand's: error (default: exit 2), warn (go on), off\n"
            "  --reference A       the alarms' saved reference (alarms.reference_file): show it,\n"
            "                      forget it (remove the file), or learn a new one in this run\n"
            "  -h, --help          this text;  --version  version\n"
            "Options take their value as the next argument or after '=' (--replay=FILE).\n"
            "Signals: SIGTERM/SIGINT drain, flush and exit 0; SIGHUP reopens the output files.\n"
            "Exit status: 0 normal end (signal, end of a replay), 1 run-time failure (source\n"
            "failed, outputs could not be written), 2 bad command line or configuration.\n");
}

/* --reference learn|show|forget: show and forget act and return the exit status; learn
 * removes the saved reference (this run learns a new one) and returns -1 (go on). */
static int reference_command(const vd_config *cfg, const char *action)
{
    const char *rf = cfg->alarm_reference_file;
    if (!cfg->alarms_enabled || cfg->alarm_test != VD_ALARM_CUSUM || !rf[0]) {
        vd_error("--reference %s: no saved reference in this configuration (it needs alarms with test = \"cusum\" "
                 "and alarms.reference_file, or STATE_DIRECTORY under systemd)",
                 action);
        return 2;
    }
    if (!strcmp(action, "show")) {
        FILE *f = fopen(rf, "re");
        if (!f) {
            printf("# no alarm reference in %s (%s): the next run learns one\n", rf, strerror(errno));
            return 0;
        }
        char buf[4096];
        size_t n;
        while ((n = fread(buf, 1, sizeof buf, f)) > 0)
            fwrite(buf, 1, n, stdout);
        fclose(f);
        return 0;
    }
    if (unlink(rf) == 0)
        vd_notice("alarm reference %s removed (--reference %s)%s", rf, action,
                  strcmp(action, "learn") ? "" : ": this run learns a new one");
    else if (errno == ENOENT)
        vd_notice("alarm reference %s: none saved (--reference %s)", rf, action);
    else {
        vd_error("--reference %s: cannot remove %s: %s", action, rf, strerror(errno));
        return 1;
    }
    return strcmp(action, "learn") ? 0 : -1;
}

static int set_override(char *dst, size_t cap, const char *val, const char *opt)
{
    if (strlen(val) >= cap) {
        fprintf(stderr, "vibidd: %s: path too long\n", opt);
        return -1;
    }
    snprintf(dst, cap, "%s", val);
    return 0;
}

int main(int argc, char **argv)
{
    setlocale(LC_NUMERIC, "C"); /* strtod in the DBC/CSV parsers needs the C locale */
    const char *cfg_path = NULL, *tracks = NULL, *influx = NULL, *record = NULL, *status = NULL, *level = NULL;
    const char *rate_check = NULL, *reference = NULL;
    bool check = false;
    vd_options opt = {NULL, false, 1.0, VD_RATE_MODE_ERROR, NULL}; /* every configured output */
    enum { O_CHECK = 256, O_REPLAY, O_PACE, O_SPEED, O_TRACKS, O_INFLUX, O_RECORD, O_STATUS, O_LOG_LEVEL,
           O_RATE_CHECK, O_REFERENCE, O_VERSION };
    static const struct option lopts[] = {
        {"config", required_argument, NULL, 'c'},        {"check", no_argument, NULL, O_CHECK},
        {"replay", required_argument, NULL, O_REPLAY},   {"pace", no_argument, NULL, O_PACE},
        {"speed", required_argument, NULL, O_SPEED},     {"tracks", required_argument, NULL, O_TRACKS},
        {"influx", required_argument, NULL, O_INFLUX},   {"record", required_argument, NULL, O_RECORD},
        {"status", required_argument, NULL, O_STATUS},   {"log-level", required_argument, NULL, O_LOG_LEVEL},
        {"rate-check", required_argument, NULL, O_RATE_CHECK}, {"reference", required_argument, NULL, O_REFERENCE},
        {"help", no_argument, NULL, 'h'},                {"version", no_argument, NULL, O_VERSION},
        {NULL, 0, NULL, 0}};
    opterr = 0; /* our own messages, naming the option as given */
    int o;
    while ((o = getopt_long(argc, argv, ":c:h", lopts, NULL)) != -1) {
        switch (o) {
        case 'c': cfg_path = optarg; break;
        case O_CHECK: check = true; break;
        case O_REPLAY: opt.replay = optarg; break;
        case O_PACE: opt.pace = true; break;
        case O_SPEED: {
            char *end;
            opt.speed = strtod(optarg, &end);
            if (end == optarg || *end || !(opt.speed >= 1e-3 && opt.speed <= 1e6)) {
                fprintf(stderr, "vibidd: --speed '%s': expected a number in [0.001, 1e6]\n", optarg);
                return 2;
            }
            break;
        }
        case O_TRACKS: tracks = optarg; break;
        case O_INFLUX: influx = optarg; break;
        case O_RECORD: record = optarg; break;
        case O_STATUS: status = optarg; break;
        case O_LOG_LEVEL: level = optarg; break;
        case O_RATE_CHECK: rate_check = optarg; break;
        case O_REFERENCE:
            if (strcmp(optarg, "learn") && strcmp(optarg, "show") && strcmp(optarg, "forget")) {
                fprintf(stderr, "vibidd: --reference '%s': expected learn, show or forget\n", optarg);
                return 2;
            }
            reference = optarg;
            break;
        case 'h': usage(stdout); return 0;
        case O_VERSION: printf("vibidd %s (libvibid %s)\n", VIBID_VERSION_STRING, vibid_version_string()); return 0;
        case ':': fprintf(stderr, "vibidd: option %s needs a value (see --help)\n", argv[optind - 1]); return 2;
        default: fprintf(stderr, "vibidd: unknown option '%s' (see --help)\n", argv[optind - 1]); return 2;
        }
    }
    if (optind < argc) {
        fprintf(stderr, "vibidd: unexpected argument '%s' (options only; see --help)\n", argv[optind]);
        return 2;
    }
    if (rate_check) {
        int m = vd_rate_mode_parse(rate_check);
        if (m < 0) {
            fprintf(stderr, "vibidd: --rate-check '%s': expected error, warn or off\n", rate_check);
            return 2;
        }
        opt.rate_check = (vd_rate_mode)m;
    }
    if (!cfg_path) {
        fprintf(stderr, "vibidd: no configuration: use -c FILE\n");
        usage(stderr);
        return 2;
    }
    vd_log_init_from_env();
    static vd_config cfg; /* large: keep it off the stack */
    vd_config_error err;
    if (vd_config_load(cfg_path, &cfg, &err)) {
        vd_error("%s", err.text);
        return 2;
    }
    if ((tracks && set_override(cfg.files.tracks_path, sizeof cfg.files.tracks_path, tracks, "--tracks")) ||
        (influx && set_override(cfg.files.influx_path, sizeof cfg.files.influx_path, influx, "--influx")) ||
        (record && set_override(cfg.files.record_path, sizeof cfg.files.record_path, record, "--record")) ||
        (status && set_override(cfg.files.status_path, sizeof cfg.files.status_path, status, "--status"))) {
        vd_config_free(&cfg);
        return 2;
    }
    {
        char perr[4 * VD_PATH_MAX];
        if (vd_config_check_paths(&cfg, opt.replay, perr, sizeof perr)) {
            vd_error("%s", perr);
            vd_config_free(&cfg);
            return 2;
        }
    }
    vd_log_set_level((vd_log_level)cfg.log_level);
    if (level) {
        int l = vd_log_level_parse(level);
        if (l < 0) {
            vd_error("--log-level '%s': expected error, warning, notice, info or debug", level);
            vd_config_free(&cfg);
            return 2;
        }
        vd_log_set_level((vd_log_level)l);
    }
    if (reference) {
        int r = reference_command(&cfg, reference);
        if (r >= 0) {
            vd_config_free(&cfg);
            return r;
        }
    }
    vd_daemon_use_output(&vd_mqtt_libmosquitto); /* outputs.mqtt (mqtt.h) */
    vd_daemon_use_output(&vd_influx_http_curl);  /* outputs.influx.http (influx_http.h) */
    if (check) {
        /* The estimator is created too: identifiability is part of a valid configuration. */
        vd_est est;
        char e2[1024];
        if (vd_est_init(&est, &cfg, e2, sizeof e2)) {
            vd_error("%s", e2);
            vd_config_free(&cfg);
            return 2;
        }
        /* whether the output-error refinement runs (the printout says so, and why) */
        if (vd_refine_resolve(&cfg, est.resolved.estimator, e2, sizeof e2)) {
            vd_error("%s", e2);
            vd_est_free(&est);
            vd_config_free(&cfg);
            return 2;
        }
        /* a replay: the capture's sample rate against the stand's (rate_check.h); the
         * outcome is a comment at the end of the printout */
        static char rate_note[3 * VD_PATH_MAX];
        if (vd_daemon_check_capture(&cfg, &opt, rate_note, sizeof rate_note, e2, sizeof e2)) {
            vd_error("%s", e2);
            vd_est_free(&est);
            vd_config_free(&cfg);
            return 2;
        }
        /* the outputs' start-up checks (output.h: directories, files, the UDP host, the
         * password, token and TLS files; no connection is made; the metrics address is bound
         * and released, as start-up binds it: in use, by the running vibidd this --check is
         * meant to replace?, is a note) */
        static char out_notes[VD_MAX_OUTPUTS * 400];
        size_t notes_len = 0;
        for (size_t i = 0; i < vd_n_outputs; i++) {
            char note[400] = "";
            int orc = vd_outputs[i]->check ? vd_outputs[i]->check(&cfg, note, sizeof note, e2, sizeof e2) : 0;
            if (orc < 0) {
                vd_error("%s", e2);
                vd_est_free(&est);
                vd_config_free(&cfg);
                return 2;
            }
            if (orc > 0 && notes_len < sizeof out_notes) {
                vd_warning("%s", note);
                int n = snprintf(out_notes + notes_len, sizeof out_notes - notes_len, "# %s\n", note);
                if (n > 0)
                    notes_len += (size_t)n;
            }
        }
        vd_config_print(&cfg, stdout);
        vd_est_print_choices(&est, stdout, "# ");
        if (rate_note[0])
            printf("# %s\n", rate_note);
        fputs(out_notes, stdout);
        vd_est_free(&est);
        vd_config_free(&cfg);
        return 0;
    }
    static vd_daemon d;
    char e3[2048];
    int rc;
    if (vd_daemon_init(&d, &cfg, &opt, e3, sizeof e3)) {
        vd_error("%s", e3);
        rc = 2;
    } else {
        rc = vd_daemon_run(&d);
    }
    vd_daemon_fini(&d);
    vd_config_free(&cfg);
    return rc;
}
