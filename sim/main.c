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
    "      --csv FILE         CSV: header t,<inputs>,<measured>[,<covariates>] by the stand's channel names\n"
    "                         (and simulation.covariates' names), one row per sample\n"
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

/* What the command line asks for, as parsed; nothing is opened yet. */
typedef struct sim_options {
    const char *stand_path, *sim_path, *csv_path, *candump_path, *can_iface, *modbus_addr;
    const char *regmap_path, *dbc_out, *regmap_out, *dump_iface;
    double duration, epoch, p_drop, p_dup, p_corrupt, fault_seed, seed_d;
    int have_seed, fd_opt, pace, quiet;
    double stop_at[SIM_MAX_SCHEDULE], resume_at[SIM_MAX_SCHEDULE];
    size_t n_stop, n_resume;
} sim_options;

enum { GO_ON = -1 }; /* parse_options and check_options: no exit yet */

/* --stop-at / --resume-at T: one more entry of its schedule (each holds at most half of
 * the fault schedule). The two options share this, they differ only in the list. */
static int add_schedule_time(const char *opt, const char *arg, double *times, size_t *n)
{
    double t;
    if (parse_num(opt, arg, 0, 1e9, &t)) return 2;
    if (*n >= SIM_MAX_SCHEDULE / 2) {
        fprintf(stderr, "vibid-sim: at most %d --stop-at and %d --resume-at\n", SIM_MAX_SCHEDULE / 2, SIM_MAX_SCHEDULE / 2);
        return 2;
    }
    times[(*n)++] = t;
    return GO_ON;
}

/* The command line into *o (getopt_long: -x V, --opt V, --opt=V). GO_ON, or the exit
 * status: 0 after --help or --version, 2 for a bad option, value or stray argument.
 * Apart from main so that reading the command line is one concern and running another. */
static int parse_options(int argc, char **argv, sim_options *o)
{
    memset(o, 0, sizeof *o);
    o->dump_iface = "can0";
    o->epoch = -1;
    o->fault_seed = 1;
    o->fd_opt = -1;
    o->pace = -1;
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
    int opt, rc = GO_ON;
    opterr = 0;
    while (rc == GO_ON && (opt = getopt_long(argc, argv, ":c:s:d:qh", lopts, NULL)) != -1) {
        switch (opt) {
        case 'c': o->stand_path = optarg; break;
        case 's': o->sim_path = optarg; break;
        case 'd': if (parse_num("--duration", optarg, 1e-9, 1e9, &o->duration)) rc = 2; break;
        case O_CSV: o->csv_path = optarg; break;
        case O_CANDUMP: o->candump_path = optarg; break;
        case O_DIFACE: o->dump_iface = optarg; break;
        case O_EPOCH: if (parse_num("--epoch", optarg, 0, 1e11, &o->epoch)) rc = 2; break;
        case O_CAN: o->can_iface = optarg; break;
        case O_FD: o->fd_opt = 1; break;
        case O_CLASSIC: o->fd_opt = 0; break;
        case O_MODBUS: o->modbus_addr = optarg; break;
        case O_REGMAP: o->regmap_path = optarg; break;
        case O_WDBC: o->dbc_out = optarg; break;
        case O_WREG: o->regmap_out = optarg; break;
        case O_RT: o->pace = 1; break;
        case O_FAST: o->pace = 0; break;
        case O_DROP: if (parse_num("--drop", optarg, 0, 1, &o->p_drop)) rc = 2; break;
        case O_DUP: if (parse_num("--duplicate", optarg, 0, 1, &o->p_dup)) rc = 2; break;
        case O_CORRUPT: if (parse_num("--corrupt", optarg, 0, 1, &o->p_corrupt)) rc = 2; break;
        case O_FSEED: if (parse_num("--fault-seed", optarg, 0, 9007199254740992.0, &o->fault_seed)) rc = 2; break;
        case O_SEED:
            if (parse_num("--seed", optarg, 0, 9007199254740992.0, &o->seed_d)) rc = 2;
            o->have_seed = 1;
            break;
        case O_STOP: rc = add_schedule_time("--stop-at", optarg, o->stop_at, &o->n_stop); break;
        case O_RESUME: rc = add_schedule_time("--resume-at", optarg, o->resume_at, &o->n_resume); break;
        case 'q': o->quiet = 1; break;
        case 'h': fputs(usage, stdout); rc = 0; break;
        case O_VERSION: printf("vibid-sim %s (libvibid %s)\n", VIBID_VERSION_STRING, vibid_version_string()); rc = 0; break;
        case ':': fprintf(stderr, "vibid-sim: option %s needs a value (see --help)\n", argv[optind - 1]); rc = 2; break;
        default: fprintf(stderr, "vibid-sim: unknown option '%s' (see --help)\n", argv[optind - 1]); rc = 2; break;
        }
    }
    if (rc == GO_ON && optind < argc) {
        fprintf(stderr, "vibid-sim: unexpected argument '%s' (see --help)\n", argv[optind]);
        rc = 2;
    }
    return rc;
}

static int is_live(const sim_options *o) { return o->can_iface || o->modbus_addr; }

/* The options together: a stand file, and something to write or serve. GO_ON or 2.
 * Apart from parsing: these are facts about the whole command line, not one option. */
static int check_options(const sim_options *o)
{
    if (!o->stand_path) {
        fprintf(stderr, "vibid-sim: no stand file: give -c STAND.cfg (see --help)\n");
        return 2;
    }
    if (!o->csv_path && !o->candump_path && !is_live(o) && !o->dbc_out && !o->regmap_out) {
        fprintf(stderr, "vibid-sim: nothing to do: give at least one of --csv, --candump, --can, --modbus, --write-dbc, --write-regmap\n");
        return 2;
    }
    return GO_ON;
}

/* Everything a run opens, in one place so that one teardown closes it whatever failed. */
typedef struct sim_run {
    vibid_stand *stand;
    sim_config cfg;
    vibid_model_dims dims;
    double h; /* s, sample period */
    sim_can_layout lay;
    vibid_regmap *loaded_map;
    vibid_regmap defmap;
    const vibid_regmap *map; /* loaded_map, &defmap or NULL */
    size_t map_chan[SIM_MAX_OUTPUTS]; /* output channel (model channel, or n_channels + covariate) of each entry */
    sim_faults faults, mb_faults;
    sim_engine *eng;
    sim_csv csv;
    vibid_candump_writer *dump;
    sim_socketcan can;
    sim_modbus *mb;
} sim_run;

/* What the sample loop counts, for the exit status and the summary. */
typedef struct sim_pacing {
    int64_t start_ns;               /* CLOCK_MONOTONIC at sample 0 */
    int64_t prev_wake;
    double j_sum, j_sum2, j_maxdev; /* s: deviation of the period between consecutive wake-ups */
    double late_max;                /* s: the latest wake-up after its deadline */
    uint64_t j_n;
} sim_pacing;

typedef struct sim_loop_stats {
    uint64_t n_samples, saturated, write_errors;
    sim_pacing pacing;
} sim_loop_stats;

/* The stand and its simulation group (-s FILE or the stand file); the sample period. 0 or
 * 2 (bad input file). */
static int load_stand_and_config(sim_run *r, const sim_options *o)
{
    vibid_stand_error serr;
    r->stand = vibid_stand_load(o->stand_path, &serr);
    if (!r->stand) {
        fprintf(stderr, "vibid-sim: %s\n", serr.text);
        return 2;
    }
    char err[1024];
    uint64_t seed = (uint64_t)o->seed_d;
    if (sim_config_load(o->sim_path ? o->sim_path : o->stand_path, r->stand, o->have_seed ? &seed : NULL, &r->cfg,
                        err, sizeof err)) {
        fprintf(stderr, "vibid-sim: %s\n", err);
        return 2;
    }
    if (o->fd_opt >= 0) r->cfg.can_fd = o->fd_opt;
    vibid_model_get_dims(vibid_stand_model(r->stand), &r->dims);
    r->h = 1.0 / vibid_stand_sample_rate(r->stand);
    return 0;
}

/* --write-dbc FILE: the DBC of the CAN frames. 0 or 1 (cannot write). */
static int write_dbc(const sim_can_layout *lay, const char *path)
{
    FILE *f = fopen(path, "w");
    if (!f) {
        fprintf(stderr, "vibid-sim: --write-dbc %s: %s\n", path, strerror(errno));
        return 1;
    }
    int bad = sim_can_write_dbc(lay, f);
    if (fclose(f) || bad) {
        fprintf(stderr, "vibid-sim: --write-dbc %s: write failed\n", path);
        return 1;
    }
    return 0;
}

/* --regmap FILE: its entries must name channels of the stand, at most 32 (the FIFO's
 * record). 0 or 2. */
static int load_register_map(sim_run *r, const sim_options *o)
{
    vibid_drv_error derr;
    r->loaded_map = vibid_regmap_load(o->regmap_path, &derr);
    if (!r->loaded_map) {
        fprintf(stderr, "vibid-sim: --regmap: %s\n", derr.text);
        return 2;
    }
    if (r->loaded_map->n > 32) {
        fprintf(stderr, "vibid-sim: --regmap %s: %zu entries; the FIFO holds at most 32 channels\n", o->regmap_path,
                r->loaded_map->n);
        return 2;
    }
    for (size_t i = 0; i < r->loaded_map->n; i++) {
        size_t c = vibid_stand_find_channel(r->stand, r->loaded_map->entries[i].name);
        for (size_t j = 0; c == (size_t)-1 && j < r->cfg.n_covariates; j++) /* a covariate is a channel too */
            if (strcmp(r->cfg.covariates[j].name, r->loaded_map->entries[i].name) == 0) c = r->dims.n_channels + j;
        if (c == (size_t)-1) {
            fprintf(stderr, "vibid-sim: %s:%u: register '%s' is not a channel of stand %s nor a covariate\n", o->regmap_path,
                    r->loaded_map->entries[i].line, r->loaded_map->entries[i].name, o->stand_path);
            return 2;
        }
        r->map_chan[i] = c;
    }
    r->map = r->loaded_map;
    return 0;
}

/* Without --regmap: every channel, then every covariate, as FLOAT32 ABCD in holding
 * registers 0, 2, 4, ... 0, 1 (out of memory) or 2 (more channels than the FIFO holds). */
static int build_default_register_map(sim_run *r)
{
    size_t nch = r->dims.n_channels, n = nch + r->cfg.n_covariates;
    if (n > 32) {
        fprintf(stderr, "vibid-sim: %zu channels%s; the Modbus FIFO holds at most 32\n", n,
                r->cfg.n_covariates ? " (covariates included)" : "");
        return 2;
    }
    r->defmap.n = n;
    r->defmap.entries = calloc(n ? n : 1, sizeof *r->defmap.entries);
    if (!r->defmap.entries) return 1;
    for (size_t i = 0; i < n; i++) {
        vibid_reg_entry *e = &r->defmap.entries[i];
        snprintf(e->name, sizeof e->name, "%s",
                 i < nch ? vibid_stand_channel_name(r->stand, i) : r->cfg.covariates[i - nch].name);
        e->address = (uint16_t)(2 * i);
        e->kind = VIBID_REG_HOLDING;
        e->type = VIBID_REG_FLOAT32;
        e->order = VIBID_REG_ABCD;
        e->scale = 1.0;
        r->map_chan[i] = i;
    }
    r->map = &r->defmap;
    return 0;
}

/* The descriptions other programs read: the CAN layout (and --write-dbc), the register map
 * (and --write-regmap). Apart from opening outputs: they exist, and are checked, before the
 * simulation starts, and a command line may ask for nothing else. 0, 1 or 2. */
static int prepare_layouts(sim_run *r, const sim_options *o)
{
    char err[1024];
    if ((o->candump_path || o->can_iface || o->dbc_out) &&
        sim_can_layout_build(r->stand, &r->cfg, &r->lay, err, sizeof err)) {
        fprintf(stderr, "vibid-sim: %s: CAN frames: %s\n", o->stand_path, err);
        return 2;
    }
    if (o->dbc_out && write_dbc(&r->lay, o->dbc_out)) return 1;
    if (!o->modbus_addr && !o->regmap_out) return 0;
    int rc = o->regmap_path ? load_register_map(r, o) : build_default_register_map(r);
    if (rc) return rc;
    if (o->regmap_out && write_regmap(o->regmap_out, r->map, &r->cfg, o->stand_path)) return 1;
    return 0;
}

/* The fault injectors (CAN frames; Modbus FIFO records with their own stream, never
 * duplicated), the --stop-at/--resume-at schedule and the signal handlers. */
static void setup_faults_and_signals(sim_run *r, const sim_options *o)
{
    sim_faults_init(&r->faults, o->p_drop, o->p_dup, o->p_corrupt, (uint64_t)o->fault_seed);
    sim_faults_init(&r->mb_faults, o->p_drop, 0.0, o->p_corrupt, (uint64_t)o->fault_seed + 0x1234567ull);
    for (size_t i = 0; i < o->n_stop; i++) sim_faults_schedule(&r->faults, o->stop_at[i], 1);
    for (size_t i = 0; i < o->n_resume; i++) sim_faults_schedule(&r->faults, o->resume_at[i], 0);
    sim_faults_install_signals();
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_term;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);
}

/* --modbus HOST:PORT into host (brackets of an IPv6 address removed) and port. -1 when
 * it is not of that form. */
static int split_host_port(const char *addr, char *host, size_t cap, double *port)
{
    const char *colon = strrchr(addr, ':');
    if (!colon || colon == addr || (size_t)(colon - addr) >= cap || parse_num("--modbus port", colon + 1, 0, 65535, port))
        return -1;
    memcpy(host, addr, (size_t)(colon - addr));
    host[colon - addr] = 0;
    if (host[0] == '[' && host[strlen(host) - 1] == ']') { /* [::1]:502 */
        memmove(host, host + 1, strlen(host));
        host[strlen(host) - 1] = 0;
    }
    return 0;
}

/* The Modbus TCP server, listening; its address on stdout (PORT 0 picks one). 0, 1 or 2. */
static int open_modbus_server(sim_run *r, const sim_options *o)
{
    char host[256], err[1024];
    double port;
    if (split_host_port(o->modbus_addr, host, sizeof host, &port)) {
        fprintf(stderr, "vibid-sim: --modbus '%s': expected HOST:PORT, e.g. 127.0.0.1:1502\n", o->modbus_addr);
        return 2;
    }
    r->mb = sim_modbus_create(host, (int)port, r->map, r->map_chan, r->cfg.fifo_base, r->cfg.fifo_capacity, r->h, err,
                              sizeof err);
    if (!r->mb) {
        fprintf(stderr, "vibid-sim: %s\n", err);
        return 1;
    }
    printf("vibid-sim: modbus TCP server listening on %s:%d (FIFO at %u, capacity %u)\n", host, sim_modbus_port(r->mb),
           r->cfg.fifo_base, r->cfg.fifo_capacity);
    fflush(stdout);
    return 0;
}

/* The engine and every output asked for, in the order the old main opened them. 0, 1
 * (cannot open an output) or 2 (the stand cannot be simulated, a bad --modbus address). */
static int open_engine_and_outputs(sim_run *r, const sim_options *o)
{
    char err[1024];
    r->eng = sim_engine_create(r->stand, &r->cfg, err, sizeof err);
    if (!r->eng) {
        fprintf(stderr, "vibid-sim: %s: %s\n", o->stand_path, err);
        return 2;
    }
    if (o->csv_path && sim_csv_open_cfg(&r->csv, o->csv_path, r->stand, &r->cfg, err, sizeof err)) {
        fprintf(stderr, "vibid-sim: %s\n", err);
        return 1;
    }
    if (o->candump_path) {
        vibid_drv_error derr;
        r->dump = vibid_candump_writer_open(o->candump_path, false, &derr);
        if (!r->dump) {
            fprintf(stderr, "vibid-sim: --candump: %s\n", derr.text);
            return 1;
        }
    }
    if (o->can_iface && sim_socketcan_open(&r->can, o->can_iface, r->cfg.can_fd, err, sizeof err)) {
        fprintf(stderr, "vibid-sim: %s\n", err);
        return 1;
    }
    return o->modbus_addr ? open_modbus_server(r, o) : 0;
}

/* Sleeps until sample k's deadline (absolute, so that errors do not accumulate) and
 * records the period's jitter and the lateness. Apart from the loop: pacing is timing,
 * the loop is data. */
static void pace_sample(sim_pacing *p, uint64_t k, double h)
{
    int64_t dl = p->start_ns + (int64_t)llround((double)k * h * 1e9);
    struct timespec ts = {dl / 1000000000, dl % 1000000000};
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR && !g_quit) {}
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    int64_t w = ts_ns(&now);
    double late = (double)(w - dl) * 1e-9;
    if (late > p->late_max) p->late_max = late;
    if (k > 0) {
        double dev = (double)(w - p->prev_wake) * 1e-9 - h;
        p->j_sum += dev;
        p->j_sum2 += dev * dev;
        if (fabs(dev) > p->j_maxdev) p->j_maxdev = fabs(dev);
        p->j_n++;
    }
    p->prev_wake = w;
}

/* One sample's CAN frames, through the fault injector, to the bus and/or the log. */
static void send_can_frames(sim_run *r, const sim_options *o, uint64_t kk, double tk, const double *values,
                            int64_t epoch_ns, sim_loop_stats *st)
{
    vibid_can_frame frames[SIM_CAN_MAX_FRAMES];
    sim_can_encode(&r->lay, kk, values, frames, &st->saturated);
    int64_t tns = epoch_ns + (int64_t)llround(tk * 1e9);
    for (size_t i = 0; i < r->lay.n_msg; i++) {
        vibid_can_frame *f = &frames[i];
        f->t_ns = tns;
        snprintf(f->iface, sizeof f->iface, "%s", o->can_iface ? o->can_iface : o->dump_iface);
        int copies = sim_faults_frame(&r->faults, f->data, f->len);
        for (int c = 0; c < copies; c++) {
            if (r->can.fd >= 0) sim_socketcan_send(&r->can, f);
            if (r->dump && vibid_candump_writer_write(r->dump, f, o->dump_iface, NULL) != VIBID_DRV_OK)
                st->write_errors++;
        }
    }
}

/* The sample loop: until `duration` s or SIGINT/SIGTERM, each sample paced (if asked),
 * served or not as the fault schedule says, simulated and written. 0, or -1 when the
 * engine fails (message printed). */
static int run_samples(sim_run *r, const sim_options *o, double duration, int pace, sim_loop_stats *st)
{
    struct timespec t_start, t_real0;
    clock_gettime(CLOCK_MONOTONIC, &t_start);
    clock_gettime(CLOCK_REALTIME, &t_real0);
    int64_t epoch_ns = o->epoch >= 0 ? (int64_t)llround(o->epoch * 1e9) : ts_ns(&t_real0);
    st->pacing.start_ns = ts_ns(&t_start);
    double values[SIM_MAX_OUTPUTS]; /* model channels, then covariates */
    for (uint64_t k = 0;; k++) {
        double t = (double)k * r->h;
        if (t >= duration - 1e-9 * r->h || g_quit) break;
        if (pace) pace_sample(&st->pacing, k, r->h);
        int change = sim_faults_update(&r->faults, t);
        if (change && r->mb) sim_modbus_set_serving(r->mb, change > 0);
        if (change && !o->quiet) fprintf(stderr, "vibid-sim: t = %.6f s: %s serving\n", t, change > 0 ? "resumed" : "stopped");
        uint64_t kk;
        double tk;
        if (sim_engine_next(r->eng, &kk, &tk, values, NULL)) {
            fprintf(stderr, "vibid-sim: %s\n", sim_engine_error(r->eng));
            return -1;
        }
        if (r->csv.f && sim_csv_write(&r->csv, tk, values)) st->write_errors++;
        if (r->faults.serving && (r->dump || r->can.fd >= 0)) send_can_frames(r, o, kk, tk, values, epoch_ns, st);
        if (r->mb && r->faults.serving) sim_modbus_push(r->mb, values, &r->mb_faults);
        st->n_samples++;
    }
    return 0;
}

/* Closes the file outputs, checking that every write reached the file. 0 or 1. */
static int close_file_outputs(sim_run *r, const sim_loop_stats *st)
{
    int rc = 0;
    char err[1024];
    if (r->csv.f && sim_csv_close(&r->csv, err, sizeof err)) {
        fprintf(stderr, "vibid-sim: %s\n", err);
        rc = 1;
    }
    if (r->dump) {
        vibid_drv_error derr;
        if (vibid_candump_writer_close(r->dump, &derr) != VIBID_DRV_OK) {
            fprintf(stderr, "vibid-sim: --candump: %s\n", derr.text);
            rc = 1;
        }
        r->dump = NULL;
    }
    if (st->write_errors) {
        fprintf(stderr, "vibid-sim: %llu writes failed\n", (unsigned long long)st->write_errors);
        rc = 1;
    }
    return rc;
}

/* The summary on stderr (unless --quiet): samples and speed, the integrator's work,
 * pacing, faults, the bus and the Modbus server's counters, saturated CAN values. */
static void print_summary(const sim_run *r, int pace, const sim_loop_stats *st, double wall)
{
    double h = r->h, simt = (double)st->n_samples * h;
    const sim_pacing *p = &st->pacing;
    sim_engine_stats es;
    sim_engine_stats_get(r->eng, &es);
    fprintf(stderr, "vibid-sim: %s: %llu samples (%.6g s simulated at %g Hz) in %.3f s wall: real-time factor %.1f; %ld intervals by the exact step, %ld by ARKODE (%ld RK steps, %ld RHS evaluations)\n",
            vibid_stand_name(r->stand), (unsigned long long)st->n_samples, simt, 1.0 / h, wall, wall > 0 ? simt / wall : INFINITY,
            es.exact_intervals, es.arkode_intervals, es.steps, es.rhs_evals);
    if (es.retried_pieces)
        fprintf(stderr, "vibid-sim: %ld pieces integrated again by Dormand-Prince 5(4) after the configured "
                        "method's error test failed repeatedly (docs/sim.md, \"Integration\")\n",
                es.retried_pieces);
    if (pace && p->j_n)
        fprintf(stderr, "vibid-sim: pacing (clock_nanosleep TIMER_ABSTIME): %llu periods of %.1f us: period jitter mean %.2f us, std %.2f us, max |dev| %.1f us; max lateness %.1f us\n",
                (unsigned long long)p->j_n, h * 1e6, p->j_sum / (double)p->j_n * 1e6,
                sqrt(fmax(0.0, p->j_sum2 / (double)p->j_n - (p->j_sum / (double)p->j_n) * (p->j_sum / (double)p->j_n))) * 1e6,
                p->j_maxdev * 1e6, p->late_max * 1e6);
    const sim_faults *f = &r->faults;
    if (f->seen)
        fprintf(stderr, "vibid-sim: CAN frames: %llu generated, %llu dropped, %llu duplicated, %llu corrupted\n",
                (unsigned long long)f->seen, (unsigned long long)f->dropped, (unsigned long long)f->duplicated,
                (unsigned long long)f->corrupted);
    if (r->can.fd >= 0)
        fprintf(stderr, "vibid-sim: %s: %llu frames sent, %llu send errors%s%s\n", r->can.iface, (unsigned long long)r->can.sent,
                (unsigned long long)r->can.tx_errors, r->can.tx_errors ? ", last: " : "", r->can.tx_errors ? strerror(r->can.last_errno) : "");
    if (r->mb) {
        sim_modbus_stats ms;
        sim_modbus_stats_get(r->mb, &ms);
        fprintf(stderr, "vibid-sim: modbus: %llu clients accepted, %llu closed, %llu requests (%llu writes refused), %llu records, "
                        "%llu sessions; FIFO records dropped %llu, corrupted %llu; %llu encode errors; %llu clients closed for not "
                        "reading their replies, %llu for bad frames\n",
                (unsigned long long)ms.accepted, (unsigned long long)ms.closed, (unsigned long long)ms.requests,
                (unsigned long long)ms.refused_writes, (unsigned long long)ms.records, (unsigned long long)ms.sessions,
                (unsigned long long)r->mb_faults.dropped, (unsigned long long)r->mb_faults.corrupted,
                (unsigned long long)ms.encode_errors, (unsigned long long)ms.slow_clients,
                (unsigned long long)ms.bad_frames);
    }
    if (st->saturated) fprintf(stderr, "vibid-sim: warning: %llu values saturated in integer CAN signals (raise the scale)\n",
                               (unsigned long long)st->saturated);
}

/* Closes whatever was opened, in reverse order; NULL-safe on a run that failed early. */
static void teardown(sim_run *r)
{
    char err[1024];
    if (r->csv.f) sim_csv_close(&r->csv, err, sizeof err);
    if (r->dump) vibid_candump_writer_close(r->dump, NULL);
    sim_socketcan_close(&r->can);
    sim_modbus_destroy(r->mb);
    sim_engine_destroy(r->eng);
    vibid_regmap_destroy(r->loaded_map);
    free(r->defmap.entries);
    sim_config_free(&r->cfg);
    vibid_stand_destroy(r->stand);
}

/* Setup, the sample loop, the closing of the outputs and the summary; the exit status. */
static int simulate(sim_run *r, const sim_options *o)
{
    int rc = load_stand_and_config(r, o);
    if (!rc) rc = prepare_layouts(r, o);
    if (rc || (!o->csv_path && !o->candump_path && !is_live(o))) return rc; /* failed, or only --write-* */
    double duration = o->duration > 0 ? o->duration : r->cfg.duration > 0 ? r->cfg.duration : (is_live(o) ? INFINITY : 10.0);
    int pace = o->pace >= 0 ? o->pace : is_live(o);
    setup_faults_and_signals(r, o);
    if ((rc = open_engine_and_outputs(r, o))) return rc;
    sim_loop_stats st;
    memset(&st, 0, sizeof st);
    if (run_samples(r, o, duration, pace, &st)) return 1;
    struct timespec t_end;
    clock_gettime(CLOCK_MONOTONIC, &t_end);
    double wall = (double)(ts_ns(&t_end) - st.pacing.start_ns) * 1e-9;
    rc = close_file_outputs(r, &st);
    if (!o->quiet) print_summary(r, pace, &st, wall);
    return rc;
}

int main(int argc, char **argv)
{
    setlocale(LC_ALL, "C");
    sim_options o;
    int rc = parse_options(argc, argv, &o);
    if (rc == GO_ON) rc = check_options(&o);
    if (rc != GO_ON) return rc;
    static sim_run run; /* zero-initialised: teardown is safe whatever step failed */
    run.can.fd = -1;
    rc = simulate(&run, &o);
    teardown(&run);
    return rc;
}
