/* vd_gen_capture: writes test captures of a stand for the daemon's tests, until vibid-sim
 * (sim/) can serve them: the stand file's model integrated with classical RK4 (20
 * substeps per sample) from rest, base excited by the paper's triangle (amplitude 1 mm,
 * 5 Hz, corners on sample instants), force inputs by sines, white noise of a given
 * fraction of each channel's RMS, and optionally a step of one parameter at a given time
 * (a 10 % stiffness loss for the diagnostics test).
 *
 * Outputs: CSV ("t,<channel names>", t in s) and/or a candump log in the layout of
 * tests/daemon/data/example1.dbc (one classic frame per channel: 16-bit counter,
 * float32 value), with optional dropped frames, corrupted lines and a truncated end.
 *
 * usage: vd_gen_capture STAND.cfg [--duration S] [--t0 EPOCH_S] [--noise REL] [--seed N]
 *          [--step NAME:FACTOR:TIME_S] [--csv F] [--candump F] [--drop FRAC]
 *          [--corrupt FRAC] [--truncate]
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <vibid/model.h>
#include <vibid/stand_file.h>
#include <vibid_drivers/candump.h>

#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif

static double tri(double t, double f, double A)
{
    double ph = fmod(t * f, 1.0); /* 0..1: rise 0->A on [0,.25], fall to -A on [.25,.75], rise to 0 */
    if (ph < 0.25)
        return A * 4.0 * ph;
    if (ph < 0.75)
        return A * (2.0 - 4.0 * ph);
    return A * (4.0 * ph - 4.0);
}
static double dtri(double t, double f, double A)
{
    double ph = fmod(t * f, 1.0);
    return (ph < 0.25 || ph >= 0.75) ? 4.0 * A * f : -4.0 * A * f;
}

static uint64_t rng = 88172645463325252ull;
static double urand(void)
{
    rng ^= rng >> 12;
    rng ^= rng << 25;
    rng ^= rng >> 27;
    return (double)((rng * 2685821657736338717ull) >> 11) * (1.0 / 9007199254740992.0);
}
static double nrand(void)
{
    double u, v, s;
    do {
        u = 2 * urand() - 1;
        v = 2 * urand() - 1;
        s = u * u + v * v;
    } while (s >= 1 || s == 0);
    return u * sqrt(-2 * log(s) / s);
}

typedef struct sim {
    const vibid_model *m;
    size_t n, r, p;
    double *theta, *Mdiag;
    int has_base;
} sim;

static void rhs(const sim *s, double t, const double *y, const double *yd, double *acc)
{
    double base[2] = {tri(t, 5.0, 1e-3), dtri(t, 5.0, 1e-3)};
    double u[16];
    for (size_t j = 0; j < s->r; j++)
        u[j] = sin(2 * M_PI * 7.0 * (1 + 0.37 * (double)j) * t);
    double f[64];
    vibid_model_forces(s->m, s->theta, y, yd, s->has_base ? base : NULL, s->r ? u : NULL, f);
    for (size_t i = 0; i < s->n; i++)
        acc[i] = f[i] / s->Mdiag[i];
}

int main(int argc, char **argv)
{
    if (argc < 2) {
        fprintf(stderr, "usage: vd_gen_capture STAND.cfg [options] (see the source)\n");
        return 2;
    }
    double duration = 10, t0 = 1700000000.0, noise = 0, drop = 0, corrupt = 0;
    const char *csv = NULL, *cd = NULL, *step = NULL;
    int truncate_end = 0;
    for (int i = 2; i < argc; i++) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!strcmp(a, "--truncate")) {
            truncate_end = 1;
            continue;
        }
        if (!v) {
            fprintf(stderr, "vd_gen_capture: %s needs a value\n", a);
            return 2;
        }
        i++;
        if (!strcmp(a, "--duration"))
            duration = atof(v);
        else if (!strcmp(a, "--t0"))
            t0 = atof(v);
        else if (!strcmp(a, "--noise"))
            noise = atof(v);
        else if (!strcmp(a, "--seed"))
            rng = strtoull(v, NULL, 10) * 2654435761ull + 1;
        else if (!strcmp(a, "--step"))
            step = v;
        else if (!strcmp(a, "--csv"))
            csv = v;
        else if (!strcmp(a, "--candump"))
            cd = v;
        else if (!strcmp(a, "--drop"))
            drop = atof(v);
        else if (!strcmp(a, "--corrupt"))
            corrupt = atof(v);
        else {
            fprintf(stderr, "vd_gen_capture: unknown option %s\n", a);
            return 2;
        }
    }
    vibid_stand_error se;
    vibid_stand *st = vibid_stand_load(argv[1], &se);
    if (!st) {
        fprintf(stderr, "vd_gen_capture: %s\n", se.text);
        return 1;
    }
    sim s = {0};
    s.m = vibid_stand_model(st);
    vibid_model_dims d;
    vibid_model_get_dims(s.m, &d);
    s.n = d.n_dof;
    s.r = d.n_inputs;
    s.p = d.n_params;
    s.has_base = d.has_base;
    s.theta = malloc(s.p * sizeof *s.theta);
    memcpy(s.theta, vibid_stand_true_values(st), s.p * sizeof *s.theta);
    double *M = calloc(s.n * s.n, sizeof *M);
    vibid_model_assemble(s.m, s.theta, M, NULL, NULL, NULL, NULL, NULL);
    s.Mdiag = malloc(s.n * sizeof *s.Mdiag);
    for (size_t i = 0; i < s.n; i++)
        s.Mdiag[i] = M[i + i * s.n];
    long step_k = -1;
    size_t step_idx = 0;
    double step_factor = 1;
    if (step) {
        char name[64];
        double ts;
        if (sscanf(step, "%63[^:]:%lf:%lf", name, &step_factor, &ts) != 3) {
            fprintf(stderr, "vd_gen_capture: --step NAME:FACTOR:TIME\n");
            return 2;
        }
        for (step_idx = 0; step_idx < s.p; step_idx++) {
            vibid_param_info pi;
            vibid_model_param_info(s.m, step_idx, &pi);
            if (!strcmp(pi.name, name))
                break;
        }
        if (step_idx == s.p) {
            fprintf(stderr, "vd_gen_capture: no unknown named %s\n", name);
            return 2;
        }
        step_k = lround(ts * vibid_stand_sample_rate(st));
    }
    const double fa = vibid_stand_sample_rate(st), h = 1.0 / fa;
    const size_t N = (size_t)llround(duration * fa), nc = d.n_channels;
    double *ch = malloc(N * nc * sizeof *ch);
    double y[64] = {0}, yd[64] = {0}, a[64];
    const int sub = 20;
    const double dt = h / sub;
    for (size_t k = 0; k < N; k++) {
        double t = (double)k * h;
        if ((long)k == step_k)
            s.theta[step_idx] *= step_factor;
        rhs(&s, t, y, yd, a);
        double base[2] = {tri(t, 5.0, 1e-3), dtri(t, 5.0, 1e-3)};
        for (size_t c = 0; c < nc; c++) {
            vibid_channel_info ci;
            vibid_model_channel_info(s.m, c, &ci);
            double v = 0;
            if (ci.kind == VIBID_CHANNEL_INPUT)
                v = sin(2 * M_PI * 7.0 * (1 + 0.37 * (double)ci.index) * t);
            else if (ci.index == VIBID_BASE)
                v = ci.kind == VIBID_CHANNEL_DISPLACEMENT ? base[0] : base[1];
            else
                v = ci.kind == VIBID_CHANNEL_DISPLACEMENT ? y[ci.index]
                    : ci.kind == VIBID_CHANNEL_VELOCITY   ? yd[ci.index]
                                                          : a[ci.index];
            ch[k * nc + c] = v;
        }
        for (int j = 0; j < sub; j++) { /* RK4 on (y, yd) */
            double tt = t + j * dt, k1y[64], k1v[64], k2y[64], k2v[64], k3y[64], k3v[64], k4y[64], k4v[64], yt[64],
                   vt[64];
            for (size_t i = 0; i < s.n; i++)
                k1y[i] = yd[i];
            rhs(&s, tt, y, yd, k1v);
            for (size_t i = 0; i < s.n; i++) {
                yt[i] = y[i] + 0.5 * dt * k1y[i];
                vt[i] = yd[i] + 0.5 * dt * k1v[i];
                k2y[i] = vt[i];
            }
            rhs(&s, tt + 0.5 * dt, yt, vt, k2v);
            for (size_t i = 0; i < s.n; i++) {
                yt[i] = y[i] + 0.5 * dt * k2y[i];
                vt[i] = yd[i] + 0.5 * dt * k2v[i];
                k3y[i] = vt[i];
            }
            rhs(&s, tt + 0.5 * dt, yt, vt, k3v);
            for (size_t i = 0; i < s.n; i++) {
                yt[i] = y[i] + dt * k3y[i];
                vt[i] = yd[i] + dt * k3v[i];
                k4y[i] = vt[i];
            }
            rhs(&s, tt + dt, yt, vt, k4v);
            for (size_t i = 0; i < s.n; i++) {
                y[i] += dt / 6 * (k1y[i] + 2 * k2y[i] + 2 * k3y[i] + k4y[i]);
                yd[i] += dt / 6 * (k1v[i] + 2 * k2v[i] + 2 * k3v[i] + k4v[i]);
            }
        }
    }
    if (noise > 0)
        for (size_t c = 0; c < nc; c++) {
            double ss = 0;
            for (size_t k = 0; k < N; k++)
                ss += ch[k * nc + c] * ch[k * nc + c];
            double sd = noise * sqrt(ss / (double)N);
            for (size_t k = 0; k < N; k++)
                ch[k * nc + c] += sd * nrand();
        }
    const int64_t t0_us = llround(t0 * 1e6);
    if (csv) {
        FILE *f = fopen(csv, "w");
        if (!f) {
            perror(csv);
            return 1;
        }
        fprintf(f, "t");
        for (size_t c = 0; c < nc; c++)
            fprintf(f, ",%s", vibid_stand_channel_name(st, c));
        fprintf(f, "\n");
        for (size_t k = 0; k < N; k++) {
            int64_t tu = t0_us + llround((double)k * h * 1e6);
            fprintf(f, "%lld.%06lld", (long long)(tu / 1000000), (long long)(tu % 1000000));
            for (size_t c = 0; c < nc; c++)
                fprintf(f, ",%.17g", ch[k * nc + c]);
            if (k + 1 < N || !truncate_end)
                fprintf(f, "\n");
        }
        fclose(f);
    }
    if (cd) {
        /* example1.dbc: one message per channel 0x100 + c: Counter (16 bit), value float32 */
        FILE *f = fopen(cd, "w");
        if (!f) {
            perror(cd);
            return 1;
        }
        for (size_t k = 0; k < N; k++) {
            int64_t t_ns = (t0_us + llround((double)k * h * 1e6)) * 1000;
            for (size_t c = 0; c < nc; c++) {
                if (drop > 0 && urand() < drop)
                    continue;
                vibid_can_frame fr;
                memset(&fr, 0, sizeof fr);
                fr.t_ns = t_ns + (int64_t)c * 1000;
                fr.id = 0x100u + (uint32_t)c;
                fr.len = 8;
                fr.data[0] = (uint8_t)(k & 0xff);
                fr.data[1] = (uint8_t)((k >> 8) & 0xff);
                float v = (float)ch[k * nc + c];
                uint32_t u;
                memcpy(&u, &v, 4);
                for (int b = 0; b < 4; b++)
                    fr.data[2 + b] = (uint8_t)(u >> (8 * b));
                char line[256];
                int n = vibid_candump_format(line, sizeof line, &fr, "vcan0");
                if (n < 0)
                    return 1;
                if (corrupt > 0 && urand() < corrupt)
                    snprintf(line, sizeof line, "(garbage line %zu)", k);
                int last = k + 1 == N && c + 1 == nc;
                fprintf(f, "%s%s", line, last && truncate_end ? "" : "\n");
            }
        }
        fclose(f);
    }
    fprintf(stderr, "vd_gen_capture: %zu samples of %zu channels at %g Hz\n", N, nc, fa);
    vibid_stand_destroy(st);
    free(ch);
    free(M);
    free(s.Mdiag);
    free(s.theta);
    return 0;
}
