/* bench_sim: real-time factor of vibid-sim's integration (sim_engine) for a 10-DOF chain
 * sampled at 10 kHz and for the paper's example 1 at 2 kHz, each with the exact step of
 * linear stands (integrator.kind "auto", the default: one matrix-vector product per
 * sample) and with ARKODE ERKStep restarted at every sample (kind "arkode", its default
 * tolerances: the yardstick, measured in the same run). Prints figures and the ratio;
 * never fails on time. Usage: bench_sim [DIR [SECONDS]] (stand files written to DIR;
 * ARKODE runs SECONDS of simulated time, default 5, the exact step 20 times as many so
 * that its wall time is not too short to measure).
 *
 * Chain: 10 masses of 1 kg, springs 1e5 N/m between neighbours and from the first mass
 * to the base, dampers 5 N s/m, a force input on the last mass (PRBS + band-limited
 * noise), base moved by a triangle wave; every displacement measured. Highest mode
 * about 100 Hz (omega h = 0.063 at 10 kHz).
 *
 * Real-time factor = simulated time / wall time (one core, this process alone).
 *
 * Then the command line's CSV output (issue 31 item 8): the chain's exact step writing every
 * sample through vibid-sim's own writer (sim_csv: shortest round-trip text, formatted in
 * its writer thread, 64 KiB written at a time) to DIR, against the same run writing with fprintf("%.17g") per value (the
 * writer before, same 1 MiB stdio buffer) and against the simulation alone. Aim: 100 times
 * real time or more with the file written. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <vibid/stand_file.h>

#include "sim_config.h"
#include "sim_engine.h"
#include "sim_output.h"

/* What each sample is written as: nothing (the integration alone), vibid-sim's CSV writer,
 * or the former fprintf("%.17g") per value. */
typedef enum { WRITE_NONE, WRITE_SIM_CSV, WRITE_PRINTF17 } write_mode;

static double now_s(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

/* Returns the real-time factor (simulated time / wall time). */
static double run_writing(const char *label, const char *path, const char *sim_path, sim_integrator kind,
                          double sim_seconds, write_mode mode, const char *out_path)
{
    vibid_stand_error serr;
    vibid_stand *st = vibid_stand_load(path, &serr);
    if (!st) {
        fprintf(stderr, "bench_sim: %s\n", serr.text);
        exit(1);
    }
    sim_config cfg;
    char err[1024];
    if (sim_config_load(sim_path, st, NULL, &cfg, err, sizeof err)) {
        fprintf(stderr, "bench_sim: %s\n", err);
        exit(1);
    }
    cfg.integrator = kind;
    sim_engine *e = sim_engine_create(st, &cfg, err, sizeof err);
    if (!e) {
        fprintf(stderr, "bench_sim: %s\n", err);
        exit(1);
    }
    double h = sim_engine_period(e), vals[64];
    size_t n = (size_t)(sim_seconds / h + 0.5);
    vibid_model_dims d;
    vibid_model_get_dims(vibid_stand_model(st), &d);
    sim_csv csv;
    FILE *plain = NULL;
    double t0 = now_s();
    if (mode == WRITE_SIM_CSV && sim_csv_open(&csv, out_path, st, err, sizeof err)) {
        fprintf(stderr, "bench_sim: %s\n", err);
        exit(1);
    }
    if (mode == WRITE_PRINTF17) {
        if (!(plain = fopen(out_path, "w"))) {
            perror(out_path);
            exit(1);
        }
        setvbuf(plain, NULL, _IOFBF, 1 << 20);
    }
    for (size_t k = 0; k < n; k++) {
        uint64_t kk;
        double t;
        if (sim_engine_next(e, &kk, &t, vals, NULL)) {
            fprintf(stderr, "bench_sim: %s\n", sim_engine_error(e));
            exit(1);
        }
        if (mode == WRITE_SIM_CSV && sim_csv_write(&csv, t, vals)) {
            fprintf(stderr, "bench_sim: %s: write failed\n", out_path);
            exit(1);
        }
        if (mode == WRITE_PRINTF17) {
            fprintf(plain, "%.17g", t);
            for (size_t i = 0; i < d.n_channels; i++) fprintf(plain, ",%.17g", vals[i]);
            fputc('\n', plain);
        }
    }
    if (mode == WRITE_SIM_CSV && sim_csv_close(&csv, err, sizeof err)) {
        fprintf(stderr, "bench_sim: %s\n", err);
        exit(1);
    }
    if (plain && (ferror(plain) | fclose(plain))) {
        fprintf(stderr, "bench_sim: %s: write failed\n", out_path);
        exit(1);
    }
    double wall = now_s() - t0;
    sim_engine_stats s;
    sim_engine_stats_get(e, &s);
    printf("%-52s %8zu samples  %7.3f s wall  %8.3f us/sample  real-time factor %8.1f  (exact step on %.0f %% of "
           "intervals; %.2f RK steps, %.1f RHS evals per sample)\n",
           label, n, wall, wall / (double)n * 1e6, sim_seconds / wall, 100.0 * (double)s.exact_intervals / (double)n,
           (double)s.steps / (double)n, (double)s.rhs_evals / (double)n);
    sim_engine_destroy(e);
    sim_config_free(&cfg);
    vibid_stand_destroy(st);
    return sim_seconds / wall;
}

static double run(const char *label, const char *path, const char *sim_path, sim_integrator kind, double sim_seconds)
{
    return run_writing(label, path, sim_path, kind, sim_seconds, WRITE_NONE, NULL);
}

/* Copies the simulation file src to dst with text inserted right after its opening
 * "simulation = {" (a setting added in front of the shipped ones). 0 or -1 (printed). */
static int copy_with_simulation_prefix(const char *src, const char *dst, const char *text)
{
    FILE *fr = fopen(src, "r"), *fw = fopen(dst, "w");
    if (!fr || !fw) {
        perror(!fr ? src : dst);
        if (fr) fclose(fr);
        if (fw) fclose(fw);
        return -1;
    }
    char line[512];
    while (fgets(line, sizeof line, fr)) {
        if (strncmp(line, "simulation = {", 14) == 0)
            fprintf(fw, "simulation = { %s%s", text, line + 14);
        else
            fputs(line, fw);
    }
    fclose(fr);
    return fclose(fw) == 0 ? 0 : -1;
}

int main(int argc, char **argv)
{
    const char *dir = argc > 1 ? argv[1] : "/tmp";
    double secs = argc > 2 ? atof(argv[2]) : 5.0;
    char path[512];
    snprintf(path, sizeof path, "%s/bench_sim_chain10.cfg", dir);
    FILE *f = fopen(path, "w");
    if (!f) {
        perror(path);
        return 1;
    }
    fprintf(f, "stand = { name = \"chain10\"; sample_rate = 10000.0;\n  nodes = (\n");
    for (int i = 1; i <= 10; i++)
        fprintf(f, "    { name = \"m%d\"; mass = 1.0; measure = { displacement = \"x%d\"; }; }%s\n", i, i, i < 10 ? "," : "");
    fprintf(f, "  );\n  base = { measure = { displacement = \"s\"; }; };\n  elements = (\n");
    fprintf(f, "    { name = \"c1\"; kind = \"spring\"; between = [\"m1\", \"base\"]; value = 1.0e5; },\n");
    fprintf(f, "    { name = \"d1\"; kind = \"damper\"; between = [\"m1\", \"ground\"]; value = 5.0; }");
    for (int i = 2; i <= 10; i++)
        fprintf(f, ",\n    { name = \"c%d\"; kind = \"spring\"; between = [\"m%d\", \"m%d\"]; unknown = true; true_value = 1.0e5; },\n"
                   "    { name = \"d%d\"; kind = \"damper\"; between = [\"m%d\", \"m%d\"]; value = 5.0; }",
                i, i, i - 1, i, i, i - 1);
    fprintf(f, "\n  );\n  inputs = ( { name = \"f\"; node = \"m10\"; gain = 1.0; channel = \"F\"; } );\n};\n");
    fprintf(f, "simulation = { seed = 1; hold = \"zoh\"; excitation = (\n"
               "  { target = \"base\"; kind = \"triangle\"; amplitude = 1.0e-3; frequency = 3.0; },\n"
               "  { target = \"f\"; kind = \"prbs\"; amplitude = 10.0; order = 15; samples_per_bit = 20; },\n"
               "  { target = \"f\"; kind = \"noise\"; amplitude = 5.0; f_high = 500.0; } );\n"
               "  noise = ( { channel = \"x10\"; snr_db = 50.0; } ); };\n");
    fclose(f);
    /* the same chain with the cheaper 5th-order method and rtol 1e-8; the shipped example 1
     * with its base held over each sample (the exact step's case: the shipped file moves it
     * smoothly, which ARKODE integrates) */
    char path2[512], path_ex1[512];
    snprintf(path2, sizeof path2, "%s/bench_sim_chain10_dp5.cfg", dir);
    snprintf(path_ex1, sizeof path_ex1, "%s/bench_sim_example1_held.cfg", dir);
    if (copy_with_simulation_prefix(path, path2, "integrator = { method = \"dormand_prince5\"; rtol = 1e-8; }; ") ||
        copy_with_simulation_prefix(VIBID_BENCH_SIM1, path_ex1, "hold = \"zoh\"; "))
        return 1;
    printf("bench_sim: vibid-sim integration speed: exact step (default for linear stands) and ARKODE ERKStep\n"
           "restarted every sample (default tolerances), same run, one core\n");
    double ex = run("10-DOF chain at 10 kHz: exact step", path, path, SIM_INTEGRATOR_AUTO, 20.0 * secs);
    double ar = run("10-DOF chain at 10 kHz: ARKODE fehlberg8, rtol 1e-10", path, path, SIM_INTEGRATOR_ARKODE, secs);
    run("10-DOF chain at 10 kHz: ARKODE dormand_prince5, rtol 1e-8", path2, path2, SIM_INTEGRATOR_ARKODE, secs);
    double ex1 = run("paper example 1 (2 DOF, base held) at 2 kHz: exact step", VIBID_BENCH_STAND1, path_ex1,
                     SIM_INTEGRATOR_AUTO, 20.0 * secs);
    double ar1 = run("paper example 1 (2 DOF, base held) at 2 kHz: ARKODE fehlberg8", VIBID_BENCH_STAND1, path_ex1,
                     SIM_INTEGRATOR_ARKODE, secs);
    run("paper example 1 (2 DOF) as shipped (base smooth) at 2 kHz: auto (ARKODE)", VIBID_BENCH_STAND1,
        VIBID_BENCH_SIM1, SIM_INTEGRATOR_AUTO, secs);
    printf("exact step / ARKODE (fehlberg8): 10-DOF chain %.0fx (target: 200x real time or more, now %.0fx), "
           "paper example 1 %.0fx\n",
           ex / ar, ex, ex1 / ar1);

    char csv_path[512];
    snprintf(csv_path, sizeof csv_path, "%s/bench_sim_chain10.csv", dir);
    /* four times the integration runs' span: 0.1-0.2 s of wall time, so that a scheduler
     * hiccup does not decide the figure (5 s read 46-135x over runs) */
    secs *= 4.0;
    printf("\nvibid-sim's CSV output (10-DOF chain at 10 kHz, exact step, 12 columns, %g s simulated, file in %s; "
           "formatting in vibid-sim's writer thread, sim_output.h):\n",
           secs, dir);
    double alone = run("simulation alone", path, path, SIM_INTEGRATOR_AUTO, secs);
    double with_csv = run_writing("simulation + vibid-sim's CSV writer (shortest round trip)", path, path,
                                  SIM_INTEGRATOR_AUTO, secs, WRITE_SIM_CSV, csv_path);
    double with_printf = run_writing("simulation + fprintf(\"%.17g\") per value (the writer before)", path, path,
                                     SIM_INTEGRATOR_AUTO, secs, WRITE_PRINTF17, csv_path);
    remove(csv_path);
    printf("CSV written at %.0fx real time (aim: 100x or more), %.1fx the fprintf writer's %.0fx (one thread); "
           "the simulation alone %.0fx\n",
           with_csv, with_csv / with_printf, with_printf, alone);
    return 0;
}
