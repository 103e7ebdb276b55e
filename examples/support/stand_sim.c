/* stand_sim.c: RK4 simulation of a vibid_model for examples and tests (stand_sim.h). */
#include "stand_sim.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Triangle wave: 0 at t = 0, rising to +amp at a quarter period, period 1 / f. */
static double triangle(double amp, double f, double t, double *slope) {
    double ph = f * t - floor(f * t); /* [0, 1) */
    if (ph < 0.25) {
        *slope = 4.0 * amp * f;
        return 4.0 * amp * ph;
    }
    if (ph < 0.75) {
        *slope = -4.0 * amp * f;
        return amp * (2.0 - 4.0 * ph);
    }
    *slope = 4.0 * amp * f;
    return amp * (4.0 * ph - 4.0);
}

typedef struct sim_ctx {
    const vibid_model *model;
    const double *theta;
    const stand_sim_config *cfg;
    size_t n, r;
    double *Minv; /* n x n */
    double *f, *u;
    double held_t; /* time at which held inputs are evaluated */
} sim_ctx;

static void inputs_at(const sim_ctx *c, double t, double base[2], double *u) {
    const stand_sim_config *cfg = c->cfg;
    double te = cfg->hold ? c->held_t : t;
    double slope = 0.0;
    base[0] = cfg->base_amplitude != 0.0 ? triangle(cfg->base_amplitude, cfg->base_freq_hz, te, &slope) : 0.0;
    base[1] = cfg->hold ? 0.0 : slope;
    for (size_t j = 0; j < c->r; ++j)
        u[j] = cfg->input_amplitude * sin(2.0 * M_PI * cfg->input_freq_hz * (1.0 + 0.37 * (double)j) * te);
}

/* state = [y; y'] (2n); deriv = [y'; M^-1 f]. */
static int deriv(sim_ctx *c, double t, const double *state, double *out) {
    size_t n = c->n;
    double base[2];
    inputs_at(c, t, base, c->u);
    if (vibid_model_forces(c->model, c->theta, state, state + n, base, c->u, c->f) != VIBID_OK) return -1;
    for (size_t i = 0; i < n; ++i) {
        out[i] = state[n + i];
        double a = 0.0;
        for (size_t k = 0; k < n; ++k) a += c->Minv[i + k * n] * c->f[k];
        out[n + i] = a;
    }
    return 0;
}

/* Inverse of a small dense matrix by Gauss-Jordan with partial pivoting. */
static int invert(size_t n, const double *A, double *Ainv) {
    double *W = malloc(n * n * sizeof *W);
    if (!W) return -1;
    memcpy(W, A, n * n * sizeof *W);
    for (size_t i = 0; i < n * n; ++i) Ainv[i] = 0.0;
    for (size_t i = 0; i < n; ++i) Ainv[i + i * n] = 1.0;
    for (size_t col = 0; col < n; ++col) {
        size_t piv = col;
        for (size_t r = col + 1; r < n; ++r)
            if (fabs(W[r + col * n]) > fabs(W[piv + col * n])) piv = r;
        if (W[piv + col * n] == 0.0) {
            free(W);
            return -1;
        }
        for (size_t k = 0; k < n; ++k) {
            double t = W[col + k * n];
            W[col + k * n] = W[piv + k * n];
            W[piv + k * n] = t;
            t = Ainv[col + k * n];
            Ainv[col + k * n] = Ainv[piv + k * n];
            Ainv[piv + k * n] = t;
        }
        double d = W[col + col * n];
        for (size_t k = 0; k < n; ++k) {
            W[col + k * n] /= d;
            Ainv[col + k * n] /= d;
        }
        for (size_t r = 0; r < n; ++r) {
            if (r == col) continue;
            double fct = W[r + col * n];
            if (fct == 0.0) continue;
            for (size_t k = 0; k < n; ++k) {
                W[r + k * n] -= fct * W[col + k * n];
                Ainv[r + k * n] -= fct * Ainv[col + k * n];
            }
        }
    }
    free(W);
    return 0;
}

int stand_sim_run(const vibid_model *model, const double *theta, const stand_sim_config *cfg, double *channels) {
    vibid_model_dims dims;
    if (vibid_model_get_dims(model, &dims) != VIBID_OK) {
        fprintf(stderr, "stand_sim: %s\n", vibid_last_error());
        return -1;
    }
    size_t n = dims.n_dof, r = dims.n_inputs, nc = dims.n_channels, N = cfg->n_samples;
    sim_ctx c = {model, theta, cfg, n, r, NULL, NULL, NULL, 0.0};
    double *M = malloc(n * n * sizeof *M);
    c.Minv = malloc(n * n * sizeof *c.Minv);
    c.f = malloc(n * sizeof *c.f);
    c.u = malloc((r + 1) * sizeof *c.u);
    double *st = calloc(2 * n, sizeof *st), *k1 = malloc(2 * n * sizeof(double)), *k2 = malloc(2 * n * sizeof(double)),
           *k3 = malloc(2 * n * sizeof(double)), *k4 = malloc(2 * n * sizeof(double)),
           *tmp = malloc(2 * n * sizeof(double)), *acc = malloc(2 * n * sizeof(double));
    int rc = -1;
    if (!M || !c.Minv || !c.f || !c.u || !st || !k1 || !k2 || !k3 || !k4 || !tmp || !acc) goto done;
    if (vibid_model_assemble(model, theta, M, NULL, NULL, NULL, NULL, NULL) != VIBID_OK || invert(n, M, c.Minv) != 0) {
        fprintf(stderr, "stand_sim: mass matrix not invertible\n");
        goto done;
    }
    vibid_channel_info *info = malloc(nc * sizeof *info);
    if (!info) goto done;
    for (size_t ch = 0; ch < nc; ++ch) vibid_model_channel_info(model, ch, &info[ch]);
    const double h = cfg->h, dt = h / cfg->substeps;
    for (size_t k = 0; k < N; ++k) {
        double t = (double)k * h;
        c.held_t = t;
        /* sample */
        double base[2];
        inputs_at(&c, t, base, c.u);
        if (deriv(&c, t, st, acc) != 0) {
            free(info);
            goto done;
        }
        for (size_t ch = 0; ch < nc; ++ch) {
            double v = 0.0;
            size_t idx = info[ch].index;
            switch (info[ch].kind) {
            case VIBID_CHANNEL_DISPLACEMENT: v = idx == VIBID_BASE ? base[0] : st[idx]; break;
            case VIBID_CHANNEL_VELOCITY: v = idx == VIBID_BASE ? base[1] : st[n + idx]; break;
            case VIBID_CHANNEL_ACCELERATION: v = idx == VIBID_BASE ? 0.0 : acc[n + idx]; break;
            case VIBID_CHANNEL_INPUT: v = c.u[idx]; break;
            }
            channels[k + ch * N] = v;
        }
        /* advance to t + h */
        for (int s = 0; s < cfg->substeps; ++s) {
            double ts = t + s * dt;
            size_t m2 = 2 * n;
            deriv(&c, ts, st, k1);
            for (size_t i = 0; i < m2; ++i) tmp[i] = st[i] + 0.5 * dt * k1[i];
            deriv(&c, ts + 0.5 * dt, tmp, k2);
            for (size_t i = 0; i < m2; ++i) tmp[i] = st[i] + 0.5 * dt * k2[i];
            deriv(&c, ts + 0.5 * dt, tmp, k3);
            for (size_t i = 0; i < m2; ++i) tmp[i] = st[i] + dt * k3[i];
            deriv(&c, ts + dt, tmp, k4);
            for (size_t i = 0; i < m2; ++i) st[i] += dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        }
    }
    free(info);
    rc = 0;
done:
    free(M);
    free(c.Minv);
    free(c.f);
    free(c.u);
    free(st);
    free(k1);
    free(k2);
    free(k3);
    free(k4);
    free(tmp);
    free(acc);
    return rc;
}

double stand_sim_normal(uint64_t *s) {
    for (;;) {
        double v[2];
        for (int i = 0; i < 2; ++i) {
            uint64_t x = *s;
            x ^= x >> 12;
            x ^= x << 25;
            x ^= x >> 27;
            *s = x;
            v[i] = (double)((x * 0x2545F4914F6CDD1DULL) >> 11) * (2.0 / 9007199254740992.0) - 1.0;
        }
        double q = v[0] * v[0] + v[1] * v[1];
        if (q > 0.0 && q < 1.0) return v[0] * sqrt(-2.0 * log(q) / q);
    }
}

void stand_sim_add_noise(double *channels, size_t n_samples, size_t n_channels, double rel, uint64_t *rng_state) {
    for (size_t ch = 0; ch < n_channels; ++ch) {
        double *col = channels + ch * n_samples, ss = 0.0;
        for (size_t k = 0; k < n_samples; ++k) ss += col[k] * col[k];
        double sigma = rel * sqrt(ss / (double)n_samples);
        for (size_t k = 0; k < n_samples; ++k) col[k] += sigma * stand_sim_normal(rng_state);
    }
}
