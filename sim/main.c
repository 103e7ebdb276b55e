/* vibid-sim: a simulated shaker controller. Integrates a stand's equations of motion
 * (SUNDIALS ARKODE) and writes or serves the sampled signals: CSV, candump log, live
 * SocketCAN, Modbus TCP. User documentation: docs/sim.md; `vibid-sim --help`. */
#include <errno.h>
#include <getopt.h>
#include <locale.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <vibid/common.h>
#include <vibid/stand_file.h>
#include <vibid/version.h>
#include <vibid_drivers/candump.h>
#include <vibid_drivers/register_map.h>

#include "sim_can.h"
#include "sim_config.h"
#include "sim_engine.h"
#include "sim_faults.h"
#include "sim_modbus.h"
#include "sim_output.h"

static const char usage[] =
    "Usage: vibid-sim -c STAND.cfg [options]\n"
    "Simulates the stand described in STAND.cfg (its `stand` group, read by the loader shared\n"
    "with vibidd; excitation, noise and parameter changes in its `simulation` group, see\n"
    "docs/sim.md) and writes or serves the sampled channels like a shaker controller would.\n"
    "\n"
    "Input:\n"
    "  -c, --config FILE      stand file (required)\n"
    "  -s, --sim FILE         read the `simulation` group from FILE instead of the stand file\n"
    "                         (e.g. to excite a stand file shared with vibidd)\n"
    "  -d, --duration S       simulated time in seconds (default: simulation.duration, else 10 s\n"
    "                         for file outputs and unlimited (until Ctrl-C) when serving live)\n"
    "      --seed N           random seed for noise and random excitation (default: simulation.seed, 1)\n"
    "Outputs (any combination; at least one, or a --write-* option):\n"
    "      --csv FILE         CSV: header t,<inputs>,<measured> by the stand's channel names, one row per sample\n"
    "      --candump FILE     candump -l log (can-utils format, 6-digit microseconds) of the CAN frames\n"
    "      --candump-iface N  interface name written in the log (default can0)\n"
    "      --epoch S          log time of sample 0 in seconds since 1970 (default: now)\n"
    "      --can IFACE        send the frames live on a SocketCAN interface (e.g. vcan0), paced in real time\n"
    "      --fd | --classic   CAN FD (one frame per sample) or classic CAN (several 8-byte frames per\n"
    "                         sample); default: simulation.can.fd, else classic\n"
    "      --modbus HOST:PORT Modbus TCP server (sample FIFO + current values), paced in real time;\n"
    "                         PORT 0 picks a free port (printed on stdout)\n"
    "      --regmap FILE      register map (libconfig `registers` list, names = channel names) for the\n"
    "                         Modbus server; default: FLOAT32 ABCD holding registers 0, 2, 4, ...\n"
    "      --write-dbc FILE   write the DBC describing the CAN frames and continue (exit if nothing else to do)\n"
    "      --write-regmap FILE write the register map in use and continue (exit if nothing else to do)\n"
    "Pacing:\n"
    "      --realtime         pace samples at the sample rate (default when --can or --modbus is given)\n"
    "      --fast             as fast as possible (default for file outputs)\n"
    "Faults (for testing a receiver's fault handling):\n"
    "      --drop P           drop each CAN frame / Modbus FIFO record with probability P (0..1)\n"
    "      --duplicate P      send each CAN frame twice with probability P\n"
    "      --corrupt P        flip one random payload bit of a CAN frame / FIFO record with probability P\n"
    "      --fault-seed N     seed of the fault decisions (default 1)\n"
    "      --stop-at T        stop serving at simulated time T s (bus silent, Modbus server closed); repeatable\n"
    "      --resume-at T      resume serving at T s (Modbus: new FIFO session); repeatable\n"
    "                         SIGUSR1 stops and SIGUSR2 resumes serving at any time\n"
    "Other:\n"
    "  -q, --quiet            no summary on stderr\n"
    "  -h, --help             this text\n"
    "      --version          version of vibid-sim and of the libvibid it runs on\n"
    "\n"
    "The simulation itself never pauses: faults and stops affect only what is sent.\n"
    "The CSV always holds every sample (the truth to compare a receiver against).\n"
    "Options take their value as the next argument or after '=' (--csv=FILE).\n"
    "Exit status: 0 success, 1 run-time failure, 2 bad command line or input file.\n";

static volatile sig_atomic_t g_quit;
static void on_term(int sig) { (void)sig; g_quit = 1; }

static int parse_num(const char *opt, const char *s, double lo, double hi, double *out)
{
    char *end = NULL;
    errno = 0;
    double v = strtod(s, &end);
    if (end == s || *end || errno || !isfinite(v) || v < lo || v > hi) {
        fprintf(stderr, "vibid-sim: %s '%s': expected a number in [%g, %g]\n", opt, s, lo, hi);
        return -1;
    }
    *out = v;
    return 0;
}

static int write_regmap(const char *path, const vibid_regmap *map, const sim_config *cfg, const char *stand_file)
{
    FILE *f = fopen(path, "w");
    if (!f) {
        fprintf(stderr, "vibid-sim: --write-regmap %s: %s\n", path, strerror(errno));
        return -1;
    }
    static const char *const tn[] = {"INT16", "UINT16", "INT32", "UINT32", "FLOAT32", "FLOAT64"};
    static const char *const on[] = {"ABCD", "DCBA", "BADC", "CDAB"};
    fprintf(f, "# Modbus register map of vibid-sim for %s (written by vibid-sim --write-regmap).\n"
               "# Current values at the addresses below; the sample FIFO (drivers/modbus_fifo_layout.md)\n"
               "# at holding register %u, capacity %u records, channels in this order.\n"
               "# Use the same channel order in the daemon's channel map.\nregisters = (\n",
            stand_file, cfg->fifo_base, cfg->fifo_capacity);
    for (size_t i = 0; i < map->n; i++) {
        const vibid_reg_entry *e = &map->entries[i];
        fprintf(f, "  { name = \"%s\"; address = %u; register = \"%s\"; type = \"%s\"; byte_order = \"%s\"; scale = %.17g; offset = %.17g; }%s\n",
                e->name, e->address, e->kind == VIBID_REG_HOLDING ? "holding" : "input", tn[e->type], on[e->order],
                e->scale, e->offset, i + 1 < map->n ? "," : "");
    }
    fprintf(f, ");\n");
    if (ferror(f) | fclose(f)) {
        fprintf(stderr, "vibid-sim: --write-regmap %s: write failed\n", path);
        return -1;
    }
    return 0;
}

static int64_t ts_ns(const struct timespec *t) { return (int64_t)t->tv_sec * 1000000000 + t->tv_nsec; }

int main(int argc, char **argv)
{
    setlocale(LC_ALL, "C");
    const char *stand_path = NULL, *sim_path = NULL, *csv_path = NULL, *candump_path = NULL, *can_iface = NULL, *modbus_addr = NULL;
    const char *regmap_path = NULL, *dbc_out = NULL, *regmap_out = NULL, *dump_iface = "can0";
    double duration = 0, epoch = -1, p_drop = 0, p_dup = 0, p_corrupt = 0, fault_seed = 1, seed_d = 0;
    int have_seed = 0, fd_opt = -1, pace = -1, quiet = 0;
    double stop_at[SIM_MAX_SCHEDULE], resume_at[SIM_MAX_SCHEDULE];
    size_t n_stop = 0, n_resume = 0;
    enum { O_CSV = 256, O_CANDUMP, O_DIFACE, O_EPOCH, O_CAN, O_FD, O_CLASSIC, O_MODBUS, O_REGMAP, O_WDBC, O_WREG,
           O_RT, O_FAST, O_DROP, O_DUP, O_CORRUPT, O_FSEED, O_STOP, O_RESUME, O_SEED, O_VERSION };
    static const struct option lopts[] = {
        {"config", required_argument, NULL, 'c'}, {"sim", required_argument, NULL, 's'}, {"duration", required_argument, NULL, 'd'},
        {"csv", required_argument, NULL, O_CSV}, {"candump", required_argument, NULL, O_CANDUMP},
        {"candump-iface", required_argument, NULL, O_DIFACE}, {"epoch", required_argument, NULL, O_EPOCH},
        {"can", required_argument, NULL, O_CAN}, {"fd", no_argument, NULL, O_FD},
        {"classic", no_argument, NULL, O_CLASSIC}, {"modbus", required_argument, NULL, O_MODBUS},
        {"regmap", required_argument, NULL, O_REGMAP}, {"write-dbc", required_argument, NULL, O_WDBC},
        {"write-regmap", required_argument, NULL, O_WREG}, {"realtime", no_argument, NULL, O_RT},
        {"fast", no_argument, NULL, O_FAST}, {"drop", required_argument, NULL, O_DROP},
        {"duplicate", required_argument, NULL, O_DUP}, {"corrupt", required_argument, NULL, O_CORRUPT},
        {"fault-seed", required_argument, NULL, O_FSEED}, {"stop-at", required_argument, NULL, O_STOP},
        {"resume-at", required_argument, NULL, O_RESUME}, {"seed", required_argument, NULL, O_SEED},
        {"quiet", no_argument, NULL, 'q'}, {"help", no_argument, NULL, 'h'},
        {"version", no_argument, NULL, O_VERSION}, {NULL, 0, NULL, 0}};
    int o;
    opterr = 0;
    while ((o = getopt_long(argc, argv, ":c:s:d:qh", lopts, NULL)) != -1) {
        switch (o) {
        case 'c': stand_path = optarg; break;
        case 's': sim_path = optarg; break;
        case 'd': if (parse_num("--duration", optarg, 1e-9, 1e9, &duration)) return 2; break;
        case O_CSV: csv_path = optarg; break;
        case O_CANDUMP: candump_path = optarg; break;
        case O_DIFACE: dump_iface = optarg; break;
        case O_EPOCH: if (parse_num("--epoch", optarg, 0, 1e11, &epoch)) return 2; break;
        case O_CAN: can_iface = optarg; break;
        case O_FD: fd_opt = 1; break;
        case O_CLASSIC: fd_opt = 0; break;
        case O_MODBUS: modbus_addr = optarg; break;
        case O_REGMAP: regmap_path = optarg; break;
        case O_WDBC: dbc_out = optarg; break;
        case O_WREG: regmap_out = optarg; break;
        case O_RT: pace = 1; break;
        case O_FAST: pace = 0; break;
        case O_DROP: if (parse_num("--drop", optarg, 0, 1, &p_drop)) return 2; break;
        case O_DUP: if (parse_num("--duplicate", optarg, 0, 1, &p_dup)) return 2; break;
        case O_CORRUPT: if (parse_num("--corrupt", optarg, 0, 1, &p_corrupt)) return 2; break;
        case O_FSEED: if (parse_num("--fault-seed", optarg, 0, 9007199254740992.0, &fault_seed)) return 2; break;
        case O_SEED: if (parse_num("--seed", optarg, 0, 9007199254740992.0, &seed_d)) return 2; have_seed = 1; break;
        case O_STOP:
        case O_RESUME: {
            double t;
            if (parse_num(o == O_STOP ? "--stop-at" : "--resume-at", optarg, 0, 1e9, &t)) return 2;
            if ((o == O_STOP ? n_stop : n_resume) >= SIM_MAX_SCHEDULE / 2) {
                fprintf(stderr, "vibid-sim: at most %d --stop-at and %d --resume-at\n", SIM_MAX_SCHEDULE / 2, SIM_MAX_SCHEDULE / 2);
                return 2;
            }
            if (o == O_STOP) stop_at[n_stop++] = t;
            else resume_at[n_resume++] = t;
            break;
        }
        case 'q': quiet = 1; break;
        case 'h': fputs(usage, stdout); return 0;
        case O_VERSION: printf("vibid-sim %s (libvibid %s)\n", VIBID_VERSION_STRING, vibid_version_string()); return 0;
        case ':': fprintf(stderr, "vibid-sim: option %s needs a value (see --help)\n", argv[optind - 1]); return 2;
        default: fprintf(stderr, "vibid-sim: unknown option '%s' (see --help)\n", argv[optind - 1]); return 2;
        }
    }
    if (optind < argc) {
        fprintf(stderr, "vibid-sim: unexpected argument '%s' (see --help)\n", argv[optind]);
        return 2;
    }
    if (!stand_path) {
        fprintf(stderr, "vibid-sim: no stand file: give -c STAND.cfg (see --help)\n");
        return 2;
    }
    int live = can_iface || modbus_addr;
    if (!csv_path && !candump_path && !live && !dbc_out && !regmap_out) {
        fprintf(stderr, "vibid-sim: nothing to do: give at least one of --csv, --candump, --can, --modbus, --write-dbc, --write-regmap\n");
        return 2;
    }

    vibid_stand_error serr;
    vibid_stand *stand = vibid_stand_load(stand_path, &serr);
    if (!stand) {
        fprintf(stderr, "vibid-sim: %s\n", serr.text);
        return 2;
    }
    sim_config cfg;
    char err[1024];
    uint64_t seed = (uint64_t)seed_d;
    if (sim_config_load(sim_path ? sim_path : stand_path, stand, have_seed ? &seed : NULL, &cfg, err, sizeof err)) {
        fprintf(stderr, "vibid-sim: %s\n", err);
        vibid_stand_destroy(stand);
        return 2;
    }
    if (fd_opt >= 0) cfg.can_fd = fd_opt;
    const vibid_model *model = vibid_stand_model(stand);
    vibid_model_dims dims;
    vibid_model_get_dims(model, &dims);
    double h = 1.0 / vibid_stand_sample_rate(stand);
    int rc = 1;
    sim_engine *eng = NULL;
    sim_csv csv = {0};
    vibid_candump_writer *dump = NULL;
    sim_socketcan can = {.fd = -1};
    sim_modbus *mb = NULL;
    vibid_regmap *loaded_map = NULL;
    vibid_regmap defmap = {0, NULL};
    size_t map_chan[64];

    sim_can_layout lay;
    int need_can = candump_path || can_iface || dbc_out;
    if (need_can && sim_can_layout_build(stand, &cfg, &lay, err, sizeof err)) {
        fprintf(stderr, "vibid-sim: %s: CAN frames: %s\n", stand_path, err);
        rc = 2;
        goto done;
    }
    if (dbc_out) {
        FILE *f = fopen(dbc_out, "w");
        if (!f) {
            fprintf(stderr, "vibid-sim: --write-dbc %s: %s\n", dbc_out, strerror(errno));
            goto done;
        }
        int bad = sim_can_write_dbc(&lay, f);
        if (fclose(f) || bad) {
            fprintf(stderr, "vibid-sim: --write-dbc %s: write failed\n", dbc_out);
            goto done;
        }
    }
    /* register map: given, or the default FLOAT32 map of every channel */
    const vibid_regmap *map = NULL;
    if (modbus_addr || regmap_out) {
        if (regmap_path) {
            vibid_drv_error derr;
            loaded_map = vibid_regmap_load(regmap_path, &derr);
            if (!loaded_map) {
                fprintf(stderr, "vibid-sim: --regmap: %s\n", derr.text);
                rc = 2;
                goto done;
            }
            if (loaded_map->n > 32) {
                fprintf(stderr, "vibid-sim: --regmap %s: %zu entries; the FIFO holds at most 32 channels\n", regmap_path, loaded_map->n);
                rc = 2;
                goto done;
            }
            for (size_t i = 0; i < loaded_map->n; i++) {
                size_t c = vibid_stand_find_channel(stand, loaded_map->entries[i].name);
                if (c == (size_t)-1) {
                    fprintf(stderr, "vibid-sim: %s:%u: register '%s' is not a channel of stand %s\n", regmap_path,
                            loaded_map->entries[i].line, loaded_map->entries[i].name, stand_path);
                    rc = 2;
                    goto done;
                }
                map_chan[i] = c;
            }
            map = loaded_map;
        } else {
            if (dims.n_channels > 32) {
                fprintf(stderr, "vibid-sim: %zu channels; the Modbus FIFO holds at most 32\n", dims.n_channels);
                rc = 2;
                goto done;
            }
            defmap.n = dims.n_channels;
            defmap.entries = calloc(dims.n_channels ? dims.n_channels : 1, sizeof *defmap.entries);
            if (!defmap.entries) goto done;
            for (size_t i = 0; i < dims.n_channels; i++) {
                vibid_reg_entry *e = &defmap.entries[i];
                snprintf(e->name, sizeof e->name, "%s", vibid_stand_channel_name(stand, i));
                e->address = (uint16_t)(2 * i);
                e->kind = VIBID_REG_HOLDING;
                e->type = VIBID_REG_FLOAT32;
                e->order = VIBID_REG_ABCD;
                e->scale = 1.0;
                map_chan[i] = i;
            }
            map = &defmap;
        }
        if (regmap_out && write_regmap(regmap_out, map, &cfg, stand_path)) goto done;
    }
    if (!csv_path && !candump_path && !live) {
        rc = 0; /* only --write-* */
        goto done;
    }

    if (duration <= 0) duration = cfg.duration > 0 ? cfg.duration : (live ? INFINITY : 10.0);
    if (pace < 0) pace = live ? 1 : 0;
    sim_faults faults, mb_faults;
    sim_faults_init(&faults, p_drop, p_dup, p_corrupt, (uint64_t)fault_seed);
    sim_faults_init(&mb_faults, p_drop, 0.0, p_corrupt, (uint64_t)fault_seed + 0x1234567ull);
    for (size_t i = 0; i < n_stop; i++) sim_faults_schedule(&faults, stop_at[i], 1);
    for (size_t i = 0; i < n_resume; i++) sim_faults_schedule(&faults, resume_at[i], 0);
    sim_faults_install_signals();
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_term;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);

    eng = sim_engine_create(stand, &cfg, err, sizeof err);
    if (!eng) {
        fprintf(stderr, "vibid-sim: %s: %s\n", stand_path, err);
        rc = 2;
        goto done;
    }
    if (csv_path && sim_csv_open(&csv, csv_path, stand, err, sizeof err)) {
        fprintf(stderr, "vibid-sim: %s\n", err);
        goto done;
    }
    if (candump_path) {
        vibid_drv_error derr;
        dump = vibid_candump_writer_open(candump_path, false, &derr);
        if (!dump) {
            fprintf(stderr, "vibid-sim: --candump: %s\n", derr.text);
            goto done;
        }
    }
    if (can_iface && sim_socketcan_open(&can, can_iface, cfg.can_fd, err, sizeof err)) {
        fprintf(stderr, "vibid-sim: %s\n", err);
        goto done;
    }
    if (modbus_addr) {
        char host[256];
        const char *colon = strrchr(modbus_addr, ':');
        double port;
        if (!colon || colon == modbus_addr || (size_t)(colon - modbus_addr) >= sizeof host ||
            parse_num("--modbus port", colon + 1, 0, 65535, &port)) {
            fprintf(stderr, "vibid-sim: --modbus '%s': expected HOST:PORT, e.g. 127.0.0.1:1502\n", modbus_addr);
            rc = 2;
            goto done;
        }
        memcpy(host, modbus_addr, (size_t)(colon - modbus_addr));
        host[colon - modbus_addr] = 0;
        if (host[0] == '[' && host[strlen(host) - 1] == ']') { /* [::1]:502 */
            memmove(host, host + 1, strlen(host));
            host[strlen(host) - 1] = 0;
        }
        mb = sim_modbus_create(host, (int)port, map, map_chan, cfg.fifo_base, cfg.fifo_capacity, h, err, sizeof err);
        if (!mb) {
            fprintf(stderr, "vibid-sim: %s\n", err);
            goto done;
        }
        printf("vibid-sim: modbus TCP server listening on %s:%d (FIFO at %u, capacity %u)\n", host, sim_modbus_port(mb),
               cfg.fifo_base, cfg.fifo_capacity);
        fflush(stdout);
    }

    struct timespec t_start, t_real0;
    clock_gettime(CLOCK_MONOTONIC, &t_start);
    clock_gettime(CLOCK_REALTIME, &t_real0);
    int64_t epoch_ns = epoch >= 0 ? (int64_t)llround(epoch * 1e9) : ts_ns(&t_real0);
    int64_t start_ns = ts_ns(&t_start);
    double values[SIM_MAX_CHANNELS];
    vibid_can_frame frames[SIM_CAN_MAX_FRAMES];
    uint64_t saturated = 0, k = 0, n_samples = 0, write_errors = 0;
    /* pacing statistics: period between consecutive wake-ups, lateness after the deadline */
    double j_sum = 0, j_sum2 = 0, j_maxdev = 0, late_max = 0;
    uint64_t j_n = 0;
    int64_t prev_wake = 0;
    int stopped_msg = 0;
    for (;;) {
        double t = (double)k * h;
        if (t >= duration - 1e-9 * h || g_quit) break;
        if (pace) {
            int64_t dl = start_ns + (int64_t)llround((double)k * h * 1e9);
            struct timespec ts = {dl / 1000000000, dl % 1000000000};
            while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR && !g_quit) {}
            struct timespec now;
            clock_gettime(CLOCK_MONOTONIC, &now);
            int64_t w = ts_ns(&now);
            double late = (double)(w - dl) * 1e-9;
            if (late > late_max) late_max = late;
            if (k > 0) {
                double dev = (double)(w - prev_wake) * 1e-9 - h;
                j_sum += dev;
                j_sum2 += dev * dev;
                if (fabs(dev) > j_maxdev) j_maxdev = fabs(dev);
                j_n++;
            }
            prev_wake = w;
        }
        int change = sim_faults_update(&faults, t);
        if (change && mb) sim_modbus_set_serving(mb, change > 0);
        if (change && !quiet) {
            fprintf(stderr, "vibid-sim: t = %.6f s: %s serving\n", t, change > 0 ? "resumed" : "stopped");
            stopped_msg = 1;
        }
        uint64_t kk;
        double tk;
        if (sim_engine_next(eng, &kk, &tk, values, NULL)) {
            fprintf(stderr, "vibid-sim: %s\n", sim_engine_error(eng));
            goto done;
        }
        if (csv.f && sim_csv_write(&csv, tk, values)) write_errors++;
        if (faults.serving && (dump || can.fd >= 0)) {
            sim_can_encode(&lay, kk, values, frames, &saturated);
            int64_t tns = epoch_ns + (int64_t)llround(tk * 1e9);
            for (size_t i = 0; i < lay.n_msg; i++) {
                vibid_can_frame *f = &frames[i];
                f->t_ns = tns;
                snprintf(f->iface, sizeof f->iface, "%s", can_iface ? can_iface : dump_iface);
                int copies = sim_faults_frame(&faults, f->data, f->len);
                for (int c = 0; c < copies; c++) {
                    if (can.fd >= 0) sim_socketcan_send(&can, f);
                    if (dump && vibid_candump_writer_write(dump, f, dump_iface, NULL) != VIBID_DRV_OK) write_errors++;
                }
            }
        }
        if (mb && faults.serving) sim_modbus_push(mb, values, &mb_faults);
        n_samples++;
        k++;
    }
    (void)stopped_msg;
    struct timespec t_end;
    clock_gettime(CLOCK_MONOTONIC, &t_end);
    double wall = (double)(ts_ns(&t_end) - start_ns) * 1e-9, simt = (double)n_samples * h;
    rc = 0;
    if (csv.f && sim_csv_close(&csv, err, sizeof err)) {
        fprintf(stderr, "vibid-sim: %s\n", err);
        rc = 1;
    }
    if (dump) {
        vibid_drv_error derr;
        if (vibid_candump_writer_close(dump, &derr) != VIBID_DRV_OK) {
            fprintf(stderr, "vibid-sim: --candump: %s\n", derr.text);
            rc = 1;
        }
        dump = NULL;
    }
    if (write_errors) {
        fprintf(stderr, "vibid-sim: %llu writes failed\n", (unsigned long long)write_errors);
        rc = 1;
    }
    if (!quiet) {
        sim_engine_stats es;
        sim_engine_stats_get(eng, &es);
        fprintf(stderr, "vibid-sim: %s: %llu samples (%.6g s simulated at %g Hz) in %.3f s wall: real-time factor %.1f; %ld intervals by the exact step, %ld by ARKODE (%ld RK steps, %ld RHS evaluations)\n",
                vibid_stand_name(stand), (unsigned long long)n_samples, simt, 1.0 / h, wall, wall > 0 ? simt / wall : INFINITY,
                es.exact_intervals, es.arkode_intervals, es.steps, es.rhs_evals);
        if (es.retried_pieces)
            fprintf(stderr, "vibid-sim: %ld pieces integrated again by Dormand-Prince 5(4) after the configured "
                            "method's error test failed repeatedly (docs/sim.md, \"Integration\")\n",
                    es.retried_pieces);
        if (pace && j_n)
            fprintf(stderr, "vibid-sim: pacing (clock_nanosleep TIMER_ABSTIME): %llu periods of %.1f us: period jitter mean %.2f us, std %.2f us, max |dev| %.1f us; max lateness %.1f us\n",
                    (unsigned long long)j_n, h * 1e6, j_sum / (double)j_n * 1e6,
                    sqrt(fmax(0.0, j_sum2 / (double)j_n - (j_sum / (double)j_n) * (j_sum / (double)j_n))) * 1e6, j_maxdev * 1e6, late_max * 1e6);
        if (faults.seen)
            fprintf(stderr, "vibid-sim: CAN frames: %llu generated, %llu dropped, %llu duplicated, %llu corrupted\n",
                    (unsigned long long)faults.seen, (unsigned long long)faults.dropped, (unsigned long long)faults.duplicated,
                    (unsigned long long)faults.corrupted);
        if (can.fd >= 0)
            fprintf(stderr, "vibid-sim: %s: %llu frames sent, %llu send errors%s%s\n", can.iface, (unsigned long long)can.sent,
                    (unsigned long long)can.tx_errors, can.tx_errors ? ", last: " : "", can.tx_errors ? strerror(can.last_errno) : "");
        if (mb) {
            sim_modbus_stats ms;
            sim_modbus_stats_get(mb, &ms);
            fprintf(stderr, "vibid-sim: modbus: %llu clients accepted, %llu closed, %llu requests (%llu writes refused), %llu records, "
                            "%llu sessions; FIFO records dropped %llu, corrupted %llu; %llu encode errors; %llu clients closed for not "
                            "reading their replies, %llu for bad frames\n",
                    (unsigned long long)ms.accepted, (unsigned long long)ms.closed, (unsigned long long)ms.requests,
                    (unsigned long long)ms.refused_writes, (unsigned long long)ms.records, (unsigned long long)ms.sessions,
                    (unsigned long long)mb_faults.dropped, (unsigned long long)mb_faults.corrupted,
                    (unsigned long long)ms.encode_errors, (unsigned long long)ms.slow_clients,
                    (unsigned long long)ms.bad_frames);
        }
        if (saturated) fprintf(stderr, "vibid-sim: warning: %llu values saturated in integer CAN signals (raise the scale)\n",
                               (unsigned long long)saturated);
    }
done:
    if (csv.f) sim_csv_close(&csv, err, sizeof err);
    if (dump) vibid_candump_writer_close(dump, NULL);
    sim_socketcan_close(&can);
    sim_modbus_destroy(mb);
    sim_engine_destroy(eng);
    vibid_regmap_destroy(loaded_map);
    free(defmap.entries);
    sim_config_free(&cfg);
    vibid_stand_destroy(stand);
    return rc;
}
