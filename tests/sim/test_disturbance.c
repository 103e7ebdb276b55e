/* sim.disturbance: the unmeasured random forces of a stand (stand.disturbances) and the
 * stand's declared measurement noise, as vibid-sim produces them (docs/sim.md).
 *
 * Stand: one mass m = 1 kg on a spring k = 25 N/m and a damper d = 2 N s/m to ground
 * (omega_n = 5 rad/s, zeta = 0.2), sampled at 20 Hz, a disturbance w on the mass. The
 * disturbance's samples w_k are held over [t_k, t_k + h), so the exact discrete model is
 * the ZOH one: x_{k+1} = Phi x_k + Gamma w_k with x = [y; y'], Phi = e^{A h},
 * Gamma = int_0^h e^{A t} dt [0; 1/m] (vibid_zoh), and the stationary covariance solves
 * P = Phi P Phi^T + sigma^2 Gamma Gamma^T. */
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

#define H 0.05 /* s: 20 Hz */
#define MAX_LAG 4000 /* the correlations decay as e^{-zeta omega_n h j} = e^{-0.05 j}: e^{-200} at the end */

/* The stand; measure and dist fill the node's measure group and the disturbance entry,
 * extra the rest of the file (a simulation group). */
static char *stand_text(const char *measure, const char *dist, const char *extra)
{
    static char buf[2048];
    snprintf(buf, sizeof buf,
             "stand = {\n  sample_rate = 20.0;\n"
             "  nodes = ( { name = \"m1\"; mass = 1.0; %s } );\n"
             "  elements = ( { name = \"k\"; kind = \"spring\"; between = [\"m1\", \"ground\"]; value = 25.0; },\n"
             "               { name = \"d\"; kind = \"damper\"; between = [\"m1\", \"ground\"]; value = 2.0; } );\n"
             "  disturbances = ( %s );\n};\n%s",
             measure, dist, extra);
    return buf;
}

typedef struct run {
    vibid_stand *st;
    sim_config cfg;
    sim_engine *e;
} run;

/* Loads the text and creates the engine; NULL engine (with err) is left to the caller. */
static void run_open(run *r, const char *name, const char *text, char *err, size_t errlen)
{
    const char *path = write_tmp(name, text);
    assert_non_null(path);
    vibid_stand_error serr;
    r->st = vibid_stand_load(path, &serr);
    if (!r->st) fail_msg("%s", serr.text);
    if (sim_config_load(path, r->st, NULL, &r->cfg, err, errlen)) fail_msg("%s", err);
    r->e = sim_engine_create(r->st, &r->cfg, err, errlen);
}

static void run_close(run *r)
{
    sim_engine_destroy(r->e);
    sim_config_free(&r->cfg);
    vibid_stand_destroy(r->st);
}

/* Phi, Gamma (2 x 2 and 2 x 1, column-major) of the stand, exact ZOH. */
static void exact_zoh(double Phi[4], double Gam[2])
{
    const double A[4] = {0.0, -25.0, 1.0, -2.0}, Bv[2] = {0.0, 1.0}; /* y'' = (-25 y - 2 y' + w) / 1 kg */
    assert_int_equal(vibid_zoh(2, 1, A, Bv, H, Phi, Gam), VIBID_OK);
}

/* Variance of y and its autocorrelation rho[0..MAX_LAG] for white held w of std sigma. */
static double exact_stationary(double sigma, double *rho)
{
    double Phi[4], Gam[2], P[4] = {0, 0, 0, 0};
    exact_zoh(Phi, Gam);
    /* P = Phi P Phi^T + sigma^2 Gamma Gamma^T by iteration: the error shrinks by |lambda|^2 =
     * e^{-0.1} per pass, so 2000 passes leave e^{-200} */
    for (int it = 0; it < 2000; it++) {
        double T[4], N[4];
        for (int i = 0; i < 2; i++)
            for (int j = 0; j < 2; j++) T[i + 2 * j] = Phi[i] * P[2 * j] + Phi[i + 2] * P[1 + 2 * j];
        for (int i = 0; i < 2; i++)
            for (int j = 0; j < 2; j++)
                N[i + 2 * j] = T[i] * Phi[j] + T[i + 2] * Phi[j + 2] + sigma * sigma * Gam[i] * Gam[j];
        for (int i = 0; i < 4; i++) P[i] = N[i];
    }
    /* E[x_{k+j} x_k^T] = Phi^j P (w_k is independent of x_k), so rho_j = (Phi^j P)_00 / P_00 */
    double C[4] = {P[0], P[1], P[2], P[3]};
    for (int j = 0; j <= MAX_LAG; j++) {
        rho[j] = C[0] / P[0];
        double N0 = Phi[0] * C[0] + Phi[2] * C[1], N1 = Phi[1] * C[0] + Phi[3] * C[1];
        double N2 = Phi[0] * C[2] + Phi[2] * C[3], N3 = Phi[1] * C[2] + Phi[3] * C[3];
        C[0] = N0, C[1] = N1, C[2] = N2, C[3] = N3;
    }
    return P[0];
}

static double rho_at(const double *rho, long j) { j = j < 0 ? -j : j; return j <= MAX_LAG ? rho[j] : 0.0; }

/* The default drive: white held samples of std 1 N. Over 400,000 samples (20,000 s) the
 * displacement's sample variance and lag-1 autocorrelation must match the exact ZOH
 * discretisation within 4 standard errors of their estimators for this correlated
 * sequence (the sampling error is what limits the comparison, the integration is exact
 * to 1e-8, see test_held_exact):
 *  - variance of a Gaussian sequence's sample variance: (2 / N) sum_j gamma_j^2, i.e. a
 *    relative standard error sqrt(2 tau / N) with tau = sum_{j in Z} rho_j^2 (11.6 here:
 *    0.76 % at N = 400,000, so 4 SE = 3 %; at 200,000 4 SE would be 4.3 %);
 *  - lag-1 autocorrelation: Bartlett's formula
 *    var(r_1) = (1 / N) sum_j (rho_{j+1}^2 + rho_{j-1} rho_{j+1} - 4 rho_1 rho_j rho_{j+1} + 2 rho_1^2 rho_j^2).
 * The first 1000 samples (50 s: the start from rest has decayed by e^{-100}) are dropped. */
static void test_stationary_variance(void **state)
{
    (void)state;
    char err[1024];
    run r;
    run_open(&r, "dist_stationary.cfg",
             stand_text("measure = { displacement = \"x1\"; };", "{ name = \"w1\"; node = \"m1\"; std = 1.0; }",
                        "simulation = { seed = 7; };\n"),
             err, sizeof err);
    if (!r.e) fail_msg("%s", err);
    assert_int_equal(sim_engine_channels(r.e), 1); /* the disturbance has no channel */
    const size_t skip = 1000, n = 400000;
    double *x = malloc(n * sizeof *x);
    assert_non_null(x);
    for (size_t k = 0; k < skip + n; k++) {
        uint64_t kk;
        double t, v;
        assert_int_equal(sim_engine_next(r.e, &kk, &t, &v, NULL), 0);
        if (k >= skip) x[k - skip] = v;
    }
    run_close(&r);

    double *rho = malloc((MAX_LAG + 1) * sizeof *rho);
    assert_non_null(rho);
    double var_exact = exact_stationary(1.0, rho);
    double tau = 0.0, var_r1 = 0.0;
    for (long j = -MAX_LAG; j <= MAX_LAG; j++) {
        double rj = rho_at(rho, j), rp = rho_at(rho, j + 1), rm = rho_at(rho, j - 1), r1 = rho[1];
        tau += rj * rj;
        var_r1 += rp * rp + rm * rp - 4.0 * r1 * rj * rp + 2.0 * r1 * r1 * rj * rj;
    }
    double se_var = sqrt(2.0 * tau / (double)n), se_r1 = sqrt(var_r1 / (double)n);

    double mean = 0.0, ss = 0.0, s1 = 0.0;
    for (size_t k = 0; k < n; k++) mean += x[k];
    mean /= (double)n;
    for (size_t k = 0; k < n; k++) ss += (x[k] - mean) * (x[k] - mean);
    for (size_t k = 0; k + 1 < n; k++) s1 += (x[k] - mean) * (x[k + 1] - mean);
    double var = ss / (double)n, r1 = s1 / ss;
    print_message("  var(x): sim %.6e, exact %.6e, relative difference %+.4f (4 SE = %.4f, tau = %.2f)\n", var,
                  var_exact, var / var_exact - 1.0, 4.0 * se_var, tau);
    print_message("  lag-1 autocorrelation: sim %.6f, exact %.6f, difference %+.2e (4 SE = %.2e)\n", r1, rho[1],
                  r1 - rho[1], 4.0 * se_r1);
    assert_true(fabs(var / var_exact - 1.0) < 4.0 * se_var);
    assert_true(fabs(r1 - rho[1]) < 4.0 * se_r1);
    free(x);
    free(rho);
}

/* Reconstructs w_k from the measured state: Gamma w_k = x_{k+1} - Phi x_k (least squares
 * over the two components); returns the largest part of x_{k+1} - Phi x_k that Gamma w_k
 * does not explain, relative to |Gamma| max |w|. */
static double reconstruct_w(sim_engine *e, size_t n, double *w)
{
    double Phi[4], Gam[2], x[2], xn[2];
    exact_zoh(Phi, Gam);
    double g2 = Gam[0] * Gam[0] + Gam[1] * Gam[1], worst = 0.0, wmax = 0.0;
    uint64_t kk;
    double t;
    assert_int_equal(sim_engine_next(e, &kk, &t, x, NULL), 0);
    for (size_t k = 0; k < n; k++) {
        assert_int_equal(sim_engine_next(e, &kk, &t, xn, NULL), 0);
        double r0 = xn[0] - Phi[0] * x[0] - Phi[2] * x[1], r1 = xn[1] - Phi[1] * x[0] - Phi[3] * x[1];
        w[k] = (Gam[0] * r0 + Gam[1] * r1) / g2;
        double e0 = r0 - Gam[0] * w[k], e1 = r1 - Gam[1] * w[k];
        worst = fmax(worst, sqrt(e0 * e0 + e1 * e1));
        wmax = fmax(wmax, fabs(w[k]));
        x[0] = xn[0], x[1] = xn[1];
    }
    return worst / (sqrt(g2) * wmax);
}

/* The held force keeps the integration exact: from displacement and velocity the
 * disturbance's samples are recovered through the exact ZOH model with a residual at the
 * integrator's level (bar 1e-8, as sim.accuracy), and the recovered default drive is
 * white with std 1 (20,000 samples: 4 standard errors are 4 sqrt(2 / N) = 4 % on the
 * variance and 4 / sqrt(N) = 0.028 on the lag-1 autocorrelation). An excitation that
 * targets the disturbance replaces the drive and is held too, even under
 * simulation.hold = "smooth". */
static void test_held_exact(void **state)
{
    (void)state;
    char err[1024];
    const size_t n = 20000;
    double *w = malloc(n * sizeof *w);
    assert_non_null(w);
    const char *meas = "measure = { displacement = \"x1\"; velocity = \"v1\"; };";
    run r;
    run_open(&r, "dist_exact.cfg",
             stand_text(meas, "{ name = \"w1\"; node = \"m1\"; std = 1.0; }", "simulation = { seed = 3; };\n"), err,
             sizeof err);
    if (!r.e) fail_msg("%s", err);
    double resid = reconstruct_w(r.e, n, w);
    run_close(&r);
    double ss = 0.0, s1 = 0.0;
    for (size_t k = 0; k < n; k++) ss += w[k] * w[k];
    for (size_t k = 0; k + 1 < n; k++) s1 += w[k] * w[k + 1];
    print_message("  default drive: residual %.2e, var(w) %.4f (4 SE %.3f), lag-1 autocorrelation %+.4f (4 SE %.3f)\n",
                  resid, ss / (double)n, 4.0 * sqrt(2.0 / (double)n), s1 / ss, 4.0 / sqrt((double)n));
    assert_true(resid < 1e-8);
    assert_true(fabs(ss / (double)n - 1.0) < 4.0 * sqrt(2.0 / (double)n));
    assert_true(fabs(s1 / ss) < 4.0 / sqrt((double)n));

    /* override: a sine of 3 N at 1.5 Hz on the disturbance, sampled and held */
    run_open(&r, "dist_override.cfg",
             stand_text(meas, "{ name = \"w1\"; node = \"m1\"; std = 1.0; }",
                        "simulation = { hold = \"smooth\";\n"
                        "  excitation = ( { target = \"w1\"; kind = \"sine\"; amplitude = 3.0; frequency = 1.5; } ); };\n"),
             err, sizeof err);
    if (!r.e) fail_msg("%s", err);
    const size_t n2 = 400;
    resid = reconstruct_w(r.e, n2, w);
    run_close(&r);
    double werr = 0.0;
    for (size_t k = 0; k < n2; k++) werr = fmax(werr, fabs(w[k] - 3.0 * sin(2.0 * M_PI * 1.5 * (double)k * H)));
    print_message("  sine on the disturbance: residual %.2e, max |w_k - 3 sin(2 pi 1.5 t_k)| = %.2e N\n", resid, werr);
    assert_true(resid < 1e-8);
    assert_true(werr < 1e-8 * 3.0);

    /* override by full-band noise (f_high omitted, which vibid-sim refused before this
     * change: "need 0 <= f_low < f_high (f_low = 0, f_high = inf Hz)") of std 2 N */
    run_open(&r, "dist_noise.cfg",
             stand_text(meas, "{ name = \"w1\"; node = \"m1\"; std = 1.0; }",
                        "simulation = { excitation = ( { target = \"w1\"; kind = \"noise\"; amplitude = 2.0; } ); };\n"),
             err, sizeof err);
    if (!r.e) fail_msg("%s", err);
    resid = reconstruct_w(r.e, n, w);
    run_close(&r);
    ss = 0.0;
    for (size_t k = 0; k < n; k++) ss += w[k] * w[k];
    print_message("  full-band noise of std 2 on the disturbance: residual %.2e, var(w) %.4f (4 SE %.3f)\n", resid,
                  ss / (double)n, 4.0 * 4.0 * sqrt(2.0 / (double)n));
    assert_true(resid < 1e-8);
    assert_true(fabs(ss / (double)n - 4.0) < 4.0 * 4.0 * sqrt(2.0 / (double)n));
    free(w);
}

/* An unknown std (std omitted) needs true_std for simulation, unless an excitation drives
 * the disturbance; an unknown excitation target names the disturbances. */
static void test_true_std_required(void **state)
{
    (void)state;
    char err[1024];
    run r;
    run_open(&r, "dist_missing.cfg",
             stand_text("measure = { displacement = \"x1\"; };", "{ name = \"w1\"; node = \"m1\"; }", ""), err,
             sizeof err);
    assert_null(r.e);
    print_message("  engine error: %s\n", err);
    assert_non_null(strstr(err, "stand.disturbances.[0].true_std: missing: disturbance 'w1' has an unknown std and "
                                "vibid-sim needs the std it simulates (give true_std > 0, or drive 'w1' from "
                                "simulation.excitation)"));
    run_close(&r);

    run_open(&r, "dist_missing_driven.cfg",
             stand_text("measure = { displacement = \"x1\"; };", "{ name = \"w1\"; node = \"m1\"; }",
                        "simulation = { excitation = ( { target = \"w1\"; kind = \"constant\"; amplitude = 2.5; } ); };\n"),
             err, sizeof err);
    if (!r.e) fail_msg("%s", err);
    double x = 0.0, t;
    uint64_t kk;
    for (int k = 0; k < 1200; k++) assert_int_equal(sim_engine_next(r.e, &kk, &t, &x, NULL), 0);
    /* static deflection 2.5 N / 25 N/m after 60 s (the transient decays as e^{-t}) */
    assert_true(fabs(x - 0.1) < 1e-9);
    run_close(&r);

    const char *text = stand_text("measure = { displacement = \"x1\"; };", "{ name = \"w1\"; node = \"m1\"; std = 1.0; }",
                                  "simulation = {\n  excitation = ( { target = \"w9\"; kind = \"constant\"; } ); };\n");
    const char *path = write_tmp("dist_bad_target.cfg", text);
    vibid_stand_error serr;
    vibid_stand *st = vibid_stand_load(path, &serr);
    if (!st) fail_msg("%s", serr.text);
    sim_config cfg;
    assert_int_not_equal(sim_config_load(path, st, NULL, &cfg, err, sizeof err), 0);
    print_message("  config error: %s\n", err);
    assert_non_null(strstr(err, "dist_bad_target.cfg:9: simulation.excitation.[0]: target 'w9' is neither \"base\" "
                                "nor a force input nor a disturbance of the stand (inputs: none; disturbances: w1)"));
    vibid_stand_destroy(st);
}

/* The stand's declared noise (stand.nodes.[0].noise) applies when simulation.noise gives
 * the channel no std or SNR. The same run without noise (simulation.noise std = 0, which
 * also shows that a given std wins) has the same state, so the difference of the two
 * outputs is the noise: over N = 20,000 samples its std must be 1e-3 within 4 standard
 * errors of a Gaussian sample std (sigma / sqrt(2 N): 2 %), its mean 0 within 4 sigma /
 * sqrt(N), and consecutive values uncorrelated (|r_1| < 4 / sqrt(N)). */
static void test_stand_noise(void **state)
{
    (void)state;
    char err[1024];
    const char *meas = "measure = { displacement = \"x1\"; }; noise = { displacement = 1.0e-3; };";
    const char *dist = "{ name = \"w1\"; node = \"m1\"; std = 1.0; }";
    run a, b;
    run_open(&a, "noise_stand.cfg", stand_text(meas, dist, "simulation = { seed = 5; };\n"), err, sizeof err);
    if (!a.e) fail_msg("%s", err);
    run_open(&b, "noise_off.cfg",
             stand_text(meas, dist, "simulation = { seed = 5; noise = ( { channel = \"x1\"; std = 0.0; } ); };\n"), err,
             sizeof err);
    if (!b.e) fail_msg("%s", err);
    assert_true(sim_engine_noise_std(a.e, 0) == 1.0e-3);
    assert_true(sim_engine_noise_std(b.e, 0) == 0.0);
    const size_t n = 20000;
    double sum = 0.0, ss = 0.0, s1 = 0.0, prev = 0.0;
    for (size_t k = 0; k < n; k++) {
        uint64_t ka, kb;
        double ta, tb, va, ca, vb;
        assert_int_equal(sim_engine_next(a.e, &ka, &ta, &va, &ca), 0);
        assert_int_equal(sim_engine_next(b.e, &kb, &tb, &vb, NULL), 0);
        assert_true(ca == vb); /* noise never reaches the state or the disturbance's stream */
        double d = va - vb;
        sum += d;
        ss += d * d;
        if (k) s1 += d * prev;
        prev = d;
    }
    run_close(&a);
    run_close(&b);
    double sd = sqrt(ss / (double)n), mean = sum / (double)n, r1 = s1 / ss;
    print_message("  stand noise: residual std %.5e (declared 1e-3, 4 SE %.1e), mean %+.2e, lag-1 %+.4f\n", sd,
                  4.0 * 1e-3 / sqrt(2.0 * (double)n), mean, r1);
    assert_true(fabs(sd - 1e-3) < 4.0 * 1e-3 / sqrt(2.0 * (double)n));
    assert_true(fabs(mean) < 4.0 * 1e-3 / sqrt((double)n));
    assert_true(fabs(r1) < 4.0 / sqrt((double)n));

    /* precedence: a std in simulation.noise wins; an entry with only a resolution does not
     * give noise, so the stand's stays */
    static const struct { const char *entry; double std; } cases[] = {
        {"std = 2.0e-3;", 2.0e-3}, {"resolution = 1.0e-6;", 1.0e-3}, {"snr_db = 200.0;", 0.0}};
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        char extra[256];
        snprintf(extra, sizeof extra, "simulation = { noise = ( { channel = \"x1\"; %s } ); };\n", cases[i].entry);
        run_open(&a, "noise_precedence.cfg", stand_text(meas, dist, extra), err, sizeof err);
        if (!a.e) fail_msg("%s", err);
        double got = sim_engine_noise_std(a.e, 0);
        print_message("  simulation.noise { %s } -> std %.3g\n", cases[i].entry, got);
        if (cases[i].std > 0.0) assert_true(got == cases[i].std);
        else assert_true(got > 0.0 && got < 1e-10 * 0.1); /* 200 dB below an RMS of some cm */
        run_close(&a);
    }
}

/* Coloured sensor noise and a sensor offset (simulation.noise correlation_time, offset; issue
 * 29: coverage is to be checked with coloured noise and offsets). The same stand as above;
 * x1 gets std 1e-3 m with correlation time 0.5 s (AR(1), a = exp(-h / 0.5) = 0.9048) and an
 * offset of 5e-3 m; the run with std = 0 has the same state, so the difference is offset +
 * noise. Over N = 20,000 samples (tolerances 4 standard errors of an AR(1) sequence):
 *  - mean 5e-3 within 4 sigma sqrt((1 + a) / ((1 - a) N)) = 1.3e-4 (the mean of correlated
 *    noise is 4.5 times less certain than of white);
 *  - std 1e-3 within 4 x sigma sqrt((1 + a^2) / (2 (1 - a^2) N)) = 6.3 %;
 *  - lag-1 autocorrelation a within 4 sqrt((1 - a^2) / N) = 0.012 (white: 0).
 * A negative correlation time is refused by name. */
static void test_coloured_noise_and_offset(void **state)
{
    (void)state;
    char err[1024];
    const char *meas = "measure = { displacement = \"x1\"; };";
    const char *dist = "{ name = \"w1\"; node = \"m1\"; std = 1.0; }";
    run a, b;
    run_open(&a, "noise_coloured.cfg",
             stand_text(meas, dist,
                        "simulation = { seed = 5; noise = ( { channel = \"x1\"; std = 1.0e-3; "
                        "correlation_time = 0.5; offset = 5.0e-3; } ); };\n"),
             err, sizeof err);
    if (!a.e) fail_msg("%s", err);
    run_open(&b, "noise_coloured_off.cfg",
             stand_text(meas, dist, "simulation = { seed = 5; noise = ( { channel = \"x1\"; std = 0.0; } ); };\n"), err,
             sizeof err);
    if (!b.e) fail_msg("%s", err);
    const size_t n = 20000;
    const double sigma = 1e-3, off = 5e-3, a1 = exp(-H / 0.5);
    double *d = malloc(n * sizeof *d);
    assert_non_null(d);
    double mean = 0.0;
    for (size_t k = 0; k < n; k++) {
        uint64_t ka, kb;
        double ta, tb, va, ca, vb;
        assert_int_equal(sim_engine_next(a.e, &ka, &ta, &va, &ca), 0);
        assert_int_equal(sim_engine_next(b.e, &kb, &tb, &vb, NULL), 0);
        assert_true(ca == vb); /* neither the noise nor the offset reaches the state */
        d[k] = va - vb;
        mean += d[k] / (double)n;
    }
    run_close(&a);
    run_close(&b);
    double ss = 0.0, s1 = 0.0;
    for (size_t k = 0; k < n; k++) {
        ss += (d[k] - mean) * (d[k] - mean);
        if (k) s1 += (d[k] - mean) * (d[k - 1] - mean);
    }
    free(d);
    double sd = sqrt(ss / (double)n), r1 = s1 / ss;
    double tol_mean = 4.0 * sigma * sqrt((1.0 + a1) / ((1.0 - a1) * (double)n));
    double tol_sd = 4.0 * sigma * sqrt((1.0 + a1 * a1) / (2.0 * (1.0 - a1 * a1) * (double)n));
    double tol_r1 = 4.0 * sqrt((1.0 - a1 * a1) / (double)n);
    print_message("  coloured noise + offset: mean %.5e (5e-3 +- %.1e), std %.5e (1e-3 +- %.1e), lag-1 %.4f (%.4f +- %.4f)\n",
                  mean, tol_mean, sd, tol_sd, r1, a1, tol_r1);
    assert_true(fabs(mean - off) < tol_mean);
    assert_true(fabs(sd - sigma) < tol_sd);
    assert_true(fabs(r1 - a1) < tol_r1);

    const char *path = write_tmp("noise_bad_corr.cfg",
                                 stand_text(meas, dist,
                                            "simulation = { noise = ( { channel = \"x1\"; std = 1.0e-3; "
                                            "correlation_time = -1.0; } ); };\n"));
    vibid_stand_error serr;
    vibid_stand *st = vibid_stand_load(path, &serr);
    if (!st) fail_msg("%s", serr.text);
    sim_config cfg;
    assert_int_equal(sim_config_load(path, st, NULL, &cfg, err, sizeof err), -1);
    print_message("  %s\n", err);
    assert_non_null(strstr(err, "simulation.noise.[0]"));
    assert_non_null(strstr(err, "correlation_time = -1 s must be >= 0"));
    vibid_stand_destroy(st);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_stationary_variance),
        cmocka_unit_test(test_held_exact),
        cmocka_unit_test(test_true_std_required),
        cmocka_unit_test(test_stand_noise),
        cmocka_unit_test(test_coloured_noise_and_offset),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
