/* sim.hold: inputs held between samples or sampled from a smooth signal, as the stand
 * declares them (`hold` of each input and of the base, vibid_model_get_hold) or as
 * simulation.hold overrides them (docs/sim.md).
 *
 * Reference: the exact discrete solution. A held base displacement s jumps at t_k, and a
 * damper to the base turns the jump into an impulse d_base (s_k - s_{k-1}); in the
 * momentum-like state
 *     z = [y; q],  q = M y' - d_base s
 * the held s enters without its derivative, z is continuous across the jumps, and
 *     y' = M^-1 (q + d_base s),   q' = -C y - D M^-1 (q + d_base s) + c_base s + B u
 * is linear with inputs held over [t_k, t_k + h): vibid_zoh (augmented matrix exponential)
 * discretizes it exactly. Smooth sine inputs a sin(omega t) are exact too, through two
 * oscillator states w = [sin omega t; cos omega t] appended to z (w' = [0 omega; -omega 0] w).
 *
 * Bar: 1e-8 relative (max_k |sim - exact| / max_k |exact| per channel kind), the bar of
 * sim.accuracy: the integrator runs at rtol 1e-10 per step and its error accumulates over
 * thousands of samples; everything else in the comparison is exact up to rounding. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <vibid/discretize.h>
#include <vibid/stand_file.h>

#include "sim_config.h"
#include "sim_engine.h"
#include "sim_test_util.h"

#define TWO_PI 6.283185307179586476925286766559
#define BAR 1e-8

/* How the reference treats input j (0..r-1 force inputs, r the base). */
typedef struct ref_input {
    int held;        /* 1: the recorded sample value held over the interval; 0: smooth sine */
    double amp, hz;  /* smooth: a sin(2 pi hz t); held with hz > 0: the recorded value must be a sin(2 pi hz t_k) */
} ref_input;

typedef struct case_result {
    double rel[3];   /* displacement, velocity, acceleration */
    double worst;
} case_result;

static vibid_stand *load_stand(const char *path)
{
    vibid_stand_error serr;
    vibid_stand *st = vibid_stand_load(path, &serr);
    if (!st) fail_msg("%s", serr.text);
    return st;
}

/* Runs n_samples of the stand/simulation text and compares every node channel with the
 * exact discrete solution for the inputs `in` (r + 1 entries). no_impulse = 1 builds the
 * reference without the held base's impulse (q = M y', the damper to the base seeing
 * s' = 0 only), to show how far that is from what the simulator produces. */
static case_result run_case(const char *name, const char *text, size_t n_samples, const ref_input *in, int no_impulse)
{
    const char *path = write_tmp(name, text);
    assert_non_null(path);
    vibid_stand *st = load_stand(path);
    sim_config cfg;
    char err[1024];
    if (sim_config_load(path, st, NULL, &cfg, err, sizeof err)) fail_msg("%s", err);
    apply_test_integrator(&cfg);
    sim_engine *e = sim_engine_create(st, &cfg, err, sizeof err);
    if (!e) fail_msg("%s", err);

    const vibid_model *m = vibid_stand_model(st);
    vibid_model_dims d;
    assert_int_equal(vibid_model_get_dims(m, &d), VIBID_OK);
    size_t n = d.n_dof, r = d.n_inputs, nv = r + 1, nch = d.n_channels;
    /* the simulator's resolved holds must be the ones this reference assumes */
    for (size_t j = 0; j < r; j++) assert_int_equal(cfg.input_smooth[j], !in[j].held);
    if (d.has_base) assert_int_equal(cfg.base_smooth, !in[r].held);
    size_t nosc = 0;
    for (size_t j = 0; j < nv; j++)
        if (!in[j].held && in[j].amp != 0.0) nosc++;
    size_t ns = 2 * n + 2 * nosc;
    double h = 1.0 / vibid_stand_sample_rate(st);
    double *M = calloc(n * n, sizeof(double)), *D = calloc(n * n, sizeof(double)), *C = calloc(n * n, sizeof(double));
    double *B = calloc(n * nv, sizeof(double)), *db = calloc(n, sizeof(double)), *cb = calloc(n, sizeof(double));
    double *A = calloc(ns * ns, sizeof(double)), *Bv = calloc(ns * nv, sizeof(double));
    double *G = calloc(ns * ns, sizeof(double)), *Gam = calloc(ns * nv, sizeof(double));
    double *X = calloc(ns, sizeof(double)), *Xn = calloc(ns, sizeof(double)), *v = calloc(nv, sizeof(double));
    double *vals = calloc(nch, sizeof(double)), *yd = calloc(n, sizeof(double)), *acc = calloc(n, sizeof(double));
    double *Minv = calloc(n, sizeof(double));
    assert_true(M && D && C && B && db && cb && A && Bv && G && Gam && X && Xn && v && vals && yd && acc && Minv);
    assert_int_equal(vibid_model_assemble(m, vibid_stand_true_values(st), M, D, C, B, db, cb), VIBID_OK);
    for (size_t i = 0; i < n; i++)
        for (size_t j = 0; j < n; j++)
            if (i != j) assert_true(M[i + j * n] == 0.0); /* lumped stands: M diagonal */
    for (size_t i = 0; i < n; i++) Minv[i] = 1.0 / M[i + i * n];
    int base_held = d.has_base && in[r].held;
    /* A = [0, M^-1; -C, -D M^-1] plus the oscillators; Bv: held force inputs and the held base */
    for (size_t i = 0; i < n; i++) {
        A[i + (n + i) * ns] = Minv[i];
        for (size_t j = 0; j < n; j++) {
            A[n + i + j * ns] = -C[i + j * n];
            A[n + i + (n + j) * ns] = -D[i + j * n] * Minv[j];
        }
    }
    size_t o = 2 * n;
    for (size_t j = 0; j < nv; j++) {
        if (j == r && !d.has_base) continue;
        if (in[j].held) {
            for (size_t i = 0; i < n; i++) {
                if (j < r) {
                    Bv[n + i + j * ns] = B[i + j * n];
                } else if (no_impulse) {
                    Bv[n + i + j * ns] = cb[i];
                } else {
                    Bv[i + j * ns] = Minv[i] * db[i];
                    double dmd = 0.0;
                    for (size_t l = 0; l < n; l++) dmd += D[i + l * n] * Minv[l] * db[l];
                    Bv[n + i + j * ns] = cb[i] - dmd;
                }
            }
        } else if (in[j].amp != 0.0) {
            double w = TWO_PI * in[j].hz, a = in[j].amp;
            for (size_t i = 0; i < n; i++) {
                if (j < r) {
                    A[n + i + o * ns] += B[i + j * n] * a;
                } else {
                    A[n + i + o * ns] += cb[i] * a;
                    A[n + i + (o + 1) * ns] += db[i] * a * w;
                }
            }
            A[o + (o + 1) * ns] = w;
            A[o + 1 + o * ns] = -w;
            X[o + 1] = 1.0; /* w(0) = [sin 0; cos 0] */
            o += 2;
        }
    }
    assert_int_equal(vibid_zoh(ns, nv, A, Bv, h, G, Gam), VIBID_OK);

    double maxerr[3] = {0, 0, 0}, maxref[3] = {0, 0, 0}, in_err = 0.0;
    for (size_t k = 0; k < n_samples; k++) {
        uint64_t kk;
        double t;
        assert_int_equal(sim_engine_next(e, &kk, &t, vals, NULL), 0);
        assert_int_equal(kk, k);
        /* held values as the simulator recorded them (the base's displacement channel) */
        for (size_t j = 0; j < nv; j++) v[j] = 0.0;
        for (size_t c = 0; c < nch; c++) {
            vibid_channel_info ci;
            vibid_model_channel_info(m, c, &ci);
            size_t j = ci.kind == VIBID_CHANNEL_INPUT ? ci.index
                       : ci.index == VIBID_BASE && ci.kind == VIBID_CHANNEL_DISPLACEMENT ? r : (size_t)-1;
            if (j == (size_t)-1) continue;
            if (in[j].held) v[j] = vals[c];
            if (in[j].hz > 0.0) /* the sample is the signal at t_k, held or smooth */
                in_err = fmax(in_err, fabs(vals[c] - in[j].amp * sin(TWO_PI * in[j].hz * t)) / fabs(in[j].amp));
        }
        if (base_held) {
            int measured = 0;
            for (size_t c = 0; c < nch; c++) {
                vibid_channel_info ci;
                vibid_model_channel_info(m, c, &ci);
                if (ci.index == VIBID_BASE && ci.kind == VIBID_CHANNEL_DISPLACEMENT) measured = 1;
            }
            assert_true(measured); /* the reference reads the held s_k from it */
        }
        /* y' right after the jumps at t_k; M y'' = q' on the interval (s' = 0 there) */
        for (size_t i = 0; i < n; i++) {
            double q = X[n + i] + (base_held && !no_impulse ? db[i] * v[r] : 0.0);
            yd[i] = Minv[i] * q;
            double qd = 0.0;
            for (size_t j = 0; j < ns; j++) qd += A[n + i + j * ns] * X[j];
            for (size_t j = 0; j < nv; j++) qd += Bv[n + i + j * ns] * v[j];
            acc[i] = Minv[i] * qd;
        }
        for (size_t c = 0; c < nch; c++) {
            vibid_channel_info ci;
            vibid_model_channel_info(m, c, &ci);
            if (ci.kind == VIBID_CHANNEL_INPUT || ci.index == VIBID_BASE) continue;
            double ref = ci.kind == VIBID_CHANNEL_DISPLACEMENT ? X[ci.index]
                         : ci.kind == VIBID_CHANNEL_VELOCITY   ? yd[ci.index]
                                                               : acc[ci.index];
            int q = (int)ci.kind;
            maxerr[q] = fmax(maxerr[q], fabs(vals[c] - ref));
            maxref[q] = fmax(maxref[q], fabs(ref));
        }
        for (size_t i = 0; i < ns; i++) {
            double a = 0.0;
            for (size_t j = 0; j < ns; j++) a += G[i + j * ns] * X[j];
            for (size_t j = 0; j < nv; j++) a += Gam[i + j * ns] * v[j];
            Xn[i] = a;
        }
        memcpy(X, Xn, ns * sizeof(double));
    }
    /* recorded input samples are a sin(omega t_k) up to the rounding of t_k = k h */
    assert_true(in_err < 1e-12);
    case_result res = {{0, 0, 0}, 0};
    static const char *const kn[] = {"displacement", "velocity", "acceleration"};
    for (int q = 0; q < 3; q++) {
        if (maxref[q] == 0) continue;
        res.rel[q] = maxerr[q] / maxref[q];
        print_message("%s%s: %s: max |sim - exact| / max |exact| = %.3g (%zu samples, max |exact| = %.3g)\n", name,
                      no_impulse ? " (reference WITHOUT the impulse)" : "", kn[q], res.rel[q], n_samples, maxref[q]);
        res.worst = fmax(res.worst, res.rel[q]);
    }
    free(M); free(D); free(C); free(B); free(db); free(cb); free(A); free(Bv); free(G); free(Gam);
    free(X); free(Xn); free(v); free(vals); free(yd); free(acc); free(Minv);
    sim_engine_destroy(e);
    sim_config_free(&cfg);
    vibid_stand_destroy(st);
    return res;
}

/* (a) One mass on a spring and a damper to the moving base, the base declared held in the
 * stand; s = sine + PRBS (jumps of up to 4e-4 m: velocity jumps d Delta s / m up to 8 mm/s). */
static void test_one_mass_held_base(void **state)
{
    (void)state;
    const char *text =
        "stand = { name = \"held_base1\"; sample_rate = 1000.0;\n"
        "  nodes = ( { name = \"m1\"; mass = 2.0; measure = { displacement = \"x1\"; velocity = \"v1\"; acceleration = \"a1\"; }; } );\n"
        "  base = { hold = \"zoh\"; measure = { displacement = \"s\"; }; };\n"
        "  elements = ( { name = \"c\"; kind = \"spring\"; between = [\"m1\", \"base\"]; value = 8.0e4; },\n"
        "               { name = \"d\"; kind = \"damper\"; between = [\"m1\", \"base\"]; value = 40.0; } ); };\n"
        "simulation = { seed = 5; excitation = (\n"
        "  { target = \"base\"; kind = \"sine\"; amplitude = 1.0e-3; frequency = 20.0; },\n"
        "  { target = \"base\"; kind = \"prbs\"; amplitude = 2.0e-4; order = 7; samples_per_bit = 5; } ); };\n";
    const ref_input in[1] = {{1, 0.0, 0.0}};
    case_result r = run_case("hold_one_mass.cfg", text, 3000, in, 0);
    assert_true(r.worst < BAR);
    /* the impulse is no detail: without it the velocities differ by percents */
    case_result wrong = run_case("hold_one_mass.cfg", text, 3000, in, 1);
    assert_true(wrong.rel[1] > 1e-2);
}

/* (a) Base-excited chain m1 - (c1, d1) - m2 - (c2, d2) - base, base held (sine + PRBS). */
static const char *chain_text(char *buf, size_t cap, const char *base_hold, const char *base_measure, const char *exc)
{
    snprintf(buf, cap,
             "stand = { name = \"chain2\"; sample_rate = 2000.0;\n"
             "  nodes = ( { name = \"m1\"; mass = 1.5; measure = { displacement = \"x1\"; velocity = \"v1\"; acceleration = \"a1\"; }; },\n"
             "            { name = \"m2\"; mass = 3.0; measure = { displacement = \"x2\"; velocity = \"v2\"; acceleration = \"a2\"; }; } );\n"
             "  base = { %s measure = { %s }; };\n"
             "  elements = ( { name = \"c1\"; kind = \"spring\"; between = [\"m1\", \"m2\"]; value = 6.0e4; },\n"
             "               { name = \"d1\"; kind = \"damper\"; between = [\"m1\", \"m2\"]; value = 15.0; },\n"
             "               { name = \"c2\"; kind = \"spring\"; between = [\"m2\", \"base\"]; unknown = true; true_value = 1.2e5; },\n"
             "               { name = \"d2\"; kind = \"damper\"; between = [\"base\", \"m2\"]; unknown = true; true_value = 30.0; } ); };\n"
             "simulation = { seed = 9; excitation = ( %s ); };\n",
             base_hold, base_measure, exc);
    return buf;
}

static void test_two_mass_chain_held_base(void **state)
{
    (void)state;
    char text[4096];
    chain_text(text, sizeof text, "hold = \"zoh\";", "displacement = \"s\";",
               "{ target = \"base\"; kind = \"sine\"; amplitude = 1.0e-3; frequency = 7.0; },\n"
               "  { target = \"base\"; kind = \"prbs\"; amplitude = 1.0e-4; order = 9; samples_per_bit = 3; }");
    const ref_input in[1] = {{1, 0.0, 0.0}};
    case_result r = run_case("hold_chain.cfg", text, 4000, in, 0);
    assert_true(r.worst < BAR);
    case_result wrong = run_case("hold_chain.cfg", text, 4000, in, 1);
    assert_true(wrong.rel[1] > 1e-2);
}

/* The same chain with a smooth base (no declaration: the default): the damper sees the
 * sine's exact s'; the base velocity channel is a omega cos(omega t_k). */
static void test_two_mass_chain_smooth_base(void **state)
{
    (void)state;
    char text[4096];
    chain_text(text, sizeof text, "", "displacement = \"s\"; velocity = \"sv\";",
               "{ target = \"base\"; kind = \"sine\"; amplitude = 1.0e-3; frequency = 7.0; }");
    const ref_input in[1] = {{0, 1.0e-3, 7.0}};
    case_result r = run_case("smooth_chain.cfg", text, 4000, in, 0);
    assert_true(r.worst < BAR);
    /* the base velocity channel: exact derivative of the sine */
    const char *path = write_tmp("smooth_chain_sv.cfg", text);
    vibid_stand *st = load_stand(path);
    sim_config cfg;
    char err[1024];
    if (sim_config_load(path, st, NULL, &cfg, err, sizeof err)) fail_msg("%s", err);
    apply_test_integrator(&cfg);
    sim_engine *e = sim_engine_create(st, &cfg, err, sizeof err);
    if (!e) fail_msg("%s", err);
    size_t sv = vibid_stand_find_channel(st, "sv");
    assert_true(sv != (size_t)-1);
    double vals[16], w = TWO_PI * 7.0, maxe = 0.0;
    for (size_t k = 0; k < 500; k++) {
        uint64_t kk;
        double t;
        assert_int_equal(sim_engine_next(e, &kk, &t, vals, NULL), 0);
        maxe = fmax(maxe, fabs(vals[sv] - 1.0e-3 * w * cos(w * t)));
    }
    /* rounding of the cosine only */
    assert_true(maxe < 1e-15);
    sim_engine_destroy(e);
    sim_config_free(&cfg);
    vibid_stand_destroy(st);
}

/* (b) Force inputs: f1 declared held, f2 smooth (not declared); then simulation.hold
 * overriding both ways. Every combination exact against its own reference. */
static void test_force_held_and_smooth(void **state)
{
    (void)state;
    static const char *const override[3] = {"", "hold = \"zoh\";", "hold = \"smooth\";"};
    static const char *const label[3] = {"force f1 held, f2 smooth (stand)", "force override zoh", "force override smooth"};
    for (int v = 0; v < 3; v++) {
        char text[4096], name[64];
        snprintf(text, sizeof text,
                 "stand = { name = \"two_forces\"; sample_rate = 1000.0;\n"
                 "  nodes = ( { name = \"m1\"; mass = 1.0; measure = { displacement = \"x1\"; velocity = \"v1\"; acceleration = \"a1\"; }; },\n"
                 "            { name = \"m2\"; mass = 3.0; measure = { displacement = \"x2\"; acceleration = \"a2\"; }; } );\n"
                 "  elements = ( { name = \"c1\"; kind = \"spring\"; between = [\"m1\", \"m2\"]; value = 5.0e3; },\n"
                 "               { name = \"d1\"; kind = \"damper\"; between = [\"m1\", \"m2\"]; value = 2.0; },\n"
                 "               { name = \"c2\"; kind = \"spring\"; between = [\"m2\", \"ground\"]; value = 2.0e4; },\n"
                 "               { name = \"d2\"; kind = \"damper\"; between = [\"m2\", \"ground\"]; value = 4.0; } );\n"
                 "  inputs = ( { name = \"f1\"; node = \"m1\"; gain = 1.0; channel = \"F1\"; hold = \"zoh\"; },\n"
                 "             { name = \"f2\"; node = \"m2\"; gain = 2.0; channel = \"F2\"; } ); };\n"
                 "simulation = { %s excitation = (\n"
                 "  { target = \"f1\"; kind = \"sine\"; amplitude = 5.0; frequency = 17.0; },\n"
                 "  { target = \"F2\"; kind = \"sine\"; amplitude = 3.0; frequency = 23.0; } ); };\n",
                 override[v]);
        snprintf(name, sizeof name, "hold_forces_%d.cfg", v);
        int h1 = v == 2 ? 0 : 1, h2 = v == 1 ? 1 : 0;
        const ref_input in[3] = {{h1, 5.0, 17.0}, {h2, 3.0, 23.0}, {0, 0.0, 0.0}};
        print_message("%s:\n", label[v]);
        case_result r = run_case(name, text, 3000, in, 0);
        assert_true(r.worst < BAR);
    }
}

/* (c) The stand file's `hold` round trip: file -> model declarations -> the simulator's
 * resolution (with and without the override) -> the impulse at t_0: a constant held base
 * s = s_0 jumps from the rest position 0 at t_0, so sample 0 has x = 0 and
 * v = d s_0 / m exactly. */
static void test_hold_round_trip(void **state)
{
    (void)state;
    static const char *const stand =
        "stand = { name = \"rt\"; sample_rate = 1000.0;\n"
        "  nodes = ( { name = \"m1\"; mass = 2.0; measure = { displacement = \"x1\"; velocity = \"v1\"; }; } );\n"
        "  base = { hold = \"zoh\"; measure = { displacement = \"s\"; }; };\n"
        "  elements = ( { name = \"c\"; kind = \"spring\"; between = [\"m1\", \"base\"]; value = 8.0e4; },\n"
        "               { name = \"d\"; kind = \"damper\"; between = [\"m1\", \"base\"]; value = 40.0; } );\n"
        "  inputs = ( { name = \"f1\"; node = \"m1\"; channel = \"F1\"; hold = \"zoh\"; },\n"
        "             { name = \"f2\"; node = \"m1\"; channel = \"F2\"; hold = \"smooth\"; },\n"
        "             { name = \"f3\"; node = \"m1\"; channel = \"F3\"; } ); };\n";
    static const char *const sims[3] = {
        "simulation = { excitation = ( { target = \"base\"; kind = \"constant\"; amplitude = 1.0e-3; } ); };\n",
        "simulation = { hold = \"smooth\"; };\n", "simulation = { hold = \"zoh\"; };\n"};
    for (int v = 0; v < 3; v++) {
        char text[4096];
        snprintf(text, sizeof text, "%s%s", stand, sims[v]);
        const char *path = write_tmp("hold_rt.cfg", text);
        vibid_stand *st = load_stand(path);
        const vibid_model *m = vibid_stand_model(st);
        vibid_hold hd;
        static const vibid_hold want[3] = {VIBID_HOLD_ZOH, VIBID_HOLD_SMOOTH, VIBID_HOLD_SMOOTH};
        for (size_t j = 0; j < 3; j++) {
            assert_int_equal(vibid_model_get_hold(m, j, &hd), VIBID_OK);
            assert_int_equal(hd, want[j]);
        }
        assert_int_equal(vibid_model_get_hold(m, VIBID_BASE, &hd), VIBID_OK);
        assert_int_equal(hd, VIBID_HOLD_ZOH);
        sim_config cfg;
        char err[1024];
        if (sim_config_load(path, st, NULL, &cfg, err, sizeof err)) fail_msg("%s", err);
        apply_test_integrator(&cfg);
        static const int smooth[3][4] = {{0, 1, 1, 0}, {1, 1, 1, 1}, {0, 0, 0, 0}}; /* f1 f2 f3 base */
        for (size_t j = 0; j < 3; j++) assert_int_equal(cfg.input_smooth[j], smooth[v][j]);
        assert_int_equal(cfg.base_smooth, smooth[v][3]);
        if (v == 0) {
            sim_engine *e = sim_engine_create(st, &cfg, err, sizeof err);
            if (!e) fail_msg("%s", err);
            double vals[8];
            uint64_t kk;
            double t;
            assert_int_equal(sim_engine_next(e, &kk, &t, vals, NULL), 0);
            /* channels: x1, v1, s, F1, F2, F3 */
            assert_true(vals[0] == 0.0);
            assert_true(fabs(vals[1] - 40.0 * 1.0e-3 / 2.0) < 1e-17);
            assert_true(vals[2] == 1.0e-3);
            /* afterwards s stays at s_0: no further jump */
            assert_int_equal(sim_engine_next(e, &kk, &t, vals, NULL), 0);
            assert_true(vals[2] == 1.0e-3);
            sim_engine_destroy(e);
        }
        sim_config_free(&cfg);
        vibid_stand_destroy(st);
    }
}

/* A held base has no velocity or acceleration a sensor could report: rejected, naming the
 * declaration (stand.base.hold) or the override (simulation.hold with its line). */
static void test_held_base_rates_rejected(void **state)
{
    (void)state;
    char text[4096], err[1024];
    chain_text(text, sizeof text, "hold = \"zoh\";", "displacement = \"s\"; velocity = \"sv\";",
               "{ target = \"base\"; kind = \"sine\"; amplitude = 1.0e-3; frequency = 7.0; }");
    const char *path = write_tmp("hold_bad1.cfg", text);
    vibid_stand *st = load_stand(path);
    sim_config cfg;
    if (sim_config_load(path, st, NULL, &cfg, err, sizeof err)) fail_msg("%s", err);
    apply_test_integrator(&cfg);
    assert_null(sim_engine_create(st, &cfg, err, sizeof err));
    print_message("rejected: %s\n", err);
    assert_non_null(strstr(err, "stand.base.hold"));
    assert_non_null(strstr(err, "velocity"));
    assert_non_null(strstr(err, "'sv'"));
    sim_config_free(&cfg);
    vibid_stand_destroy(st);

    /* not declared in the stand, held by the override */
    chain_text(text, sizeof text, "", "displacement = \"s\"; acceleration = \"sa\";",
               "{ target = \"base\"; kind = \"sine\"; amplitude = 1.0e-3; frequency = 7.0; }");
    char *sim = strstr(text, "simulation = {");
    assert_non_null(sim);
    char tail[1024];
    snprintf(tail, sizeof tail, "simulation = {\n  hold = \"zoh\";%s", sim + strlen("simulation = {"));
    snprintf(sim, sizeof text - (size_t)(sim - text), "%s", tail);
    path = write_tmp("hold_bad2.cfg", text);
    st = load_stand(path);
    assert_int_equal(sim_config_load(path, st, NULL, &cfg, err, sizeof err), -1);
    print_message("rejected: %s\n", err);
    assert_non_null(strstr(err, "hold_bad2.cfg:10: simulation.hold: \"zoh\" holds the base, whose acceleration is measured"));
    vibid_stand_destroy(st);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_one_mass_held_base),
        cmocka_unit_test(test_two_mass_chain_held_base),
        cmocka_unit_test(test_two_mass_chain_smooth_base),
        cmocka_unit_test(test_force_held_and_smooth),
        cmocka_unit_test(test_hold_round_trip),
        cmocka_unit_test(test_held_base_rates_rejected),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
