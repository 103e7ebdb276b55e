/* demo_identify.c: identify damping and stiffness of a one-mass oscillator from a
 * sampled force and displacement record, with the estimator core only.
 *
 *   m x'' + d x' + c x = u(t)        m = 2 kg (known), d = 4 N s/m, c = 8000 N/m
 *
 * Natural frequency sqrt(c/m)/(2 pi) = 10.07 Hz, damping ratio d/(2 sqrt(c m)) = 0.016.
 * The force is a random staircase held over each sample (zero-order hold, (1.10)),
 * sampled at 1 kHz, i.e. about 100 samples per period: central differences (1.17) then
 * carry a bias of order (omega h)^2 / 12 = 3e-4, well below what the demo prints.
 *
 * Regression form of (1.4) with m known and x', x'' from central differences:
 *   u_k - m x''_k = [x'_k  x_k] [d; c]
 * solved by batch least squares (QR) and by recursive least squares (Bierman UD),
 * first on exact data, then with 1 % white noise on the displacement, where the
 * differentiated noise biases least squares (the later issues add the remedies).
 */
#include <vibid/vibid.h>

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

enum { N_SAMPLES = 20000, SUBSTEPS = 50 };
static const double TWO_PI = 6.283185307179586; /* strict C11 has no M_PI */
static const double MASS = 2.0, DAMPING = 4.0, STIFFNESS = 8000.0, RATE_HZ = 1000.0;

static uint64_t rng_state = 0x9E3779B97F4A7C15ull;
static double uniform01(void) {
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 7;
    rng_state ^= rng_state << 17;
    return (double)(rng_state >> 11) * 0x1.0p-53;
}
static double normal01(void) {
    double u1 = uniform01(), u2 = uniform01();
    if (u1 < 1e-300) u1 = 1e-300;
    return sqrt(-2.0 * log(u1)) * cos(TWO_PI * u2);
}

/* x' = v, v' = (u - d v - c x) / m, integrated by RK4 with SUBSTEPS steps per sample. */
static void simulate(double *x, double *u) {
    const double h = 1.0 / RATE_HZ, dt = h / SUBSTEPS;
    double pos = 0.0, vel = 0.0;
    for (int k = 0; k < N_SAMPLES; ++k) {
        x[k] = pos;
        u[k] = (uniform01() < 0.5 ? -1.0 : 1.0) * (5.0 + 5.0 * uniform01()); /* N */
        for (int s = 0; s < SUBSTEPS; ++s) {
#define ACC(p, v) ((u[k] - DAMPING * (v) - STIFFNESS * (p)) / MASS)
            double k1x = vel, k1v = ACC(pos, vel);
            double k2x = vel + 0.5 * dt * k1v, k2v = ACC(pos + 0.5 * dt * k1x, vel + 0.5 * dt * k1v);
            double k3x = vel + 0.5 * dt * k2v, k3v = ACC(pos + 0.5 * dt * k2x, vel + 0.5 * dt * k2v);
            double k4x = vel + dt * k3v, k4v = ACC(pos + dt * k3x, vel + dt * k3v);
#undef ACC
            pos += dt / 6.0 * (k1x + 2 * k2x + 2 * k3x + k4x);
            vel += dt / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v);
        }
    }
}

static int check(vibid_status s, const char *what) {
    if (s != VIBID_OK) {
        fprintf(stderr, "demo: %s failed: %s (%s)\n", what, vibid_strerror(s), vibid_last_error());
        return 1;
    }
    return 0;
}

static void print_row(const char *method, const double est[2], const double se[2]) {
    const double f0 = sqrt(est[1] / MASS) / TWO_PI, zeta = est[0] / (2.0 * sqrt(est[1] * MASS));
    printf("  %-22s d = %9.4f +- %7.4f N s/m (%+7.3f %%)   c = %10.2f +- %6.2f N/m (%+7.3f %%)   f0 = %6.3f Hz  zeta = %.5f\n",
           method, est[0], se[0], 100.0 * (est[0] / DAMPING - 1.0), est[1], se[1],
           100.0 * (est[1] / STIFFNESS - 1.0), f0, zeta);
}

static int identify(const double *x, const double *u, const char *label) {
    const double h = 1.0 / RATE_HZ;
    const size_t rows = N_SAMPLES - 2;
    double *X = malloc(sizeof(double) * rows * 2), *Y = malloc(sizeof(double) * rows);
    if (!X || !Y) return 1;
    for (size_t r = 0; r < rows; ++r) {
        size_t k = r + 1;
        double vel = (x[k + 1] - x[k - 1]) / (2.0 * h);
        double acc = (x[k + 1] - 2.0 * x[k] + x[k - 1]) / (h * h);
        X[r] = vel;
        X[r + rows] = x[k];
        Y[r] = u[k] - MASS * acc;
    }
    printf("%s (N = %zu rows):\n", label, rows);
    double theta[2], se[2];
    int rc = 0;

    vibid_lsq *lsq = vibid_lsq_create(2, 1);
    if (!lsq) {
        fprintf(stderr, "demo: vibid_lsq_create failed: %s\n", vibid_last_error());
        return 1;
    }
    rc |= check(vibid_lsq_add_rows(lsq, rows, X, Y, NULL), "vibid_lsq_add_rows") ||
          check(vibid_lsq_solve(lsq, theta, NULL), "vibid_lsq_solve") ||
          check(vibid_lsq_stderr(lsq, se), "vibid_lsq_stderr");
    if (!rc) print_row("batch LS (QR)", theta, se);
    vibid_lsq_destroy(lsq);

    vibid_rls_config cfg;
    vibid_rls_config_init(&cfg, 2, 1);
    cfg.alpha = 1e-12; /* weak prior: P0 = 1e12 I against parameters of order 1e4 */
    vibid_rls *rls = vibid_rls_create(&cfg);
    if (!rls) {
        fprintf(stderr, "demo: vibid_rls_create failed: %s\n", vibid_last_error());
        return 1;
    }
    for (size_t r = 0; r < rows && !rc; ++r) {
        double xr[2] = {X[r], X[r + rows]};
        rc |= check(vibid_rls_update(rls, xr, &Y[r]), "vibid_rls_update");
    }
    rc |= rc || check(vibid_rls_theta(rls, theta), "vibid_rls_theta") || check(vibid_rls_stderr(rls, se), "vibid_rls_stderr");
    if (!rc) print_row("recursive LS (Bierman)", theta, se);
    vibid_rls_destroy(rls);
    free(X);
    free(Y);
    return rc;
}

int main(void) {
    double *x = malloc(sizeof(double) * N_SAMPLES), *u = malloc(sizeof(double) * N_SAMPLES);
    if (!x || !u) return 1;
    printf("vibid %s demo: one-mass oscillator, m = %.1f kg (known), sampled at %.0f Hz\n",
           vibid_version_string(), MASS, RATE_HZ);
    printf("  truth                  d = %9.4f N s/m                 c = %10.2f N/m                 f0 = %6.3f Hz  zeta = %.5f\n\n",
           DAMPING, STIFFNESS, sqrt(STIFFNESS / MASS) / TWO_PI, DAMPING / (2.0 * sqrt(STIFFNESS * MASS)));
    simulate(x, u);
    int rc = identify(x, u, "exact displacement");

    double rms = 0.0;
    for (int k = 0; k < N_SAMPLES; ++k) rms += x[k] * x[k];
    rms = sqrt(rms / N_SAMPLES);
    for (int k = 0; k < N_SAMPLES; ++k) x[k] += 0.01 * rms * normal01();
    printf("\n");
    rc |= identify(x, u, "displacement with 1 % white noise (LS on differentiated noise is biased)");
    free(x);
    free(u);
    return rc;
}
