/* tests/ident/capture.h: simulated captures for the identification tests: the stand is
 * simulated once by vibid-sim's engine (sim_core), then noise realisations are drawn on
 * its clean channels. Header-only (static functions), included by one test each. */
#ifndef IDENT_CAPTURE_H
#define IDENT_CAPTURE_H

#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#include <vibid/stand_file.h>

#include "sim_config.h"
#include "sim_engine.h"
#include "sim_test_util.h"

/* SANITIZED: 1 in the AddressSanitizer build (-O1, about 10x slower), where the Monte
 * Carlo studies run a few realisations for the code paths and leave the statistics to the
 * -Werror build. */
#if defined(__SANITIZE_ADDRESS__)
#define SANITIZED 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define SANITIZED 1
#else
#define SANITIZED 0
#endif
#else
#define SANITIZED 0
#endif

typedef struct capture {
    vibid_stand *stand;
    size_t n, nch, p;
    double *clean;    /* n x nch column-major */
    double *noisy;    /* scratch */
    int *noisy_chan;  /* 1 where sensor noise is added */
    double *rms;
    const double *truth;
} capture;

/* Standard normal variate (polar Box-Muller) from the xorshift stream *state. */
static double normal_from(uint64_t *state)
{
    double u, v, s;
    do {
        *state ^= *state << 13; *state ^= *state >> 7; *state ^= *state << 17;
        u = 2.0 * ((double)(*state >> 11) / 9007199254740992.0) - 1.0;
        *state ^= *state << 13; *state ^= *state >> 7; *state ^= *state << 17;
        v = 2.0 * ((double)(*state >> 11) / 9007199254740992.0) - 1.0;
        s = u * u + v * v;
    } while (s >= 1.0 || s == 0.0);
    return u * sqrt(-2.0 * log(s) / s);
}

static uint64_t rng_state = 0x9E3779B97F4A7C15ull;
static double normal(void) { return normal_from(&rng_state); }

/* Simulates n samples of the stand in `text` (written to <tmp>/name) with vibid-sim's engine. */
static void simulate(capture *c, const char *name, const char *text, size_t n)
{
    const char *path = write_tmp(name, text);
    assert_non_null(path);
    vibid_stand_error serr;
    c->stand = vibid_stand_load(path, &serr);
    if (!c->stand) fail_msg("%s", serr.text);
    sim_config cfg;
    char err[1024];
    if (sim_config_load(path, c->stand, NULL, &cfg, err, sizeof err)) fail_msg("%s", err);
    sim_engine *e = sim_engine_create(c->stand, &cfg, err, sizeof err);
    if (!e) fail_msg("%s", err);
    const vibid_model *m = vibid_stand_model(c->stand);
    vibid_model_dims d;
    assert_int_equal(vibid_model_get_dims(m, &d), VIBID_OK);
    c->n = n;
    c->nch = d.n_channels;
    c->p = d.n_params;
    c->truth = vibid_stand_true_values(c->stand);
    c->clean = malloc(c->n * c->nch * sizeof(double));
    c->noisy = malloc(c->n * c->nch * sizeof(double));
    c->noisy_chan = calloc(c->nch, sizeof(int));
    c->rms = calloc(c->nch, sizeof(double));
    double *vals = malloc(c->nch * sizeof(double)), *cl = malloc(c->nch * sizeof(double));
    assert_true(c->clean && c->noisy && c->noisy_chan && c->rms && vals && cl);
    for (size_t k = 0; k < c->n; k++) {
        uint64_t kk;
        double t;
        if (sim_engine_next(e, &kk, &t, vals, cl)) fail_msg("%s", sim_engine_error(e));
        for (size_t j = 0; j < c->nch; j++) c->clean[k + j * c->n] = cl[j];
    }
    for (size_t j = 0; j < c->nch; j++) {
        vibid_channel_info ci;
        assert_int_equal(vibid_model_channel_info(m, j, &ci), VIBID_OK);
        c->noisy_chan[j] = ci.kind != VIBID_CHANNEL_INPUT;
        double s2 = 0.0;
        for (size_t k = 0; k < c->n; k++) s2 += c->clean[k + j * c->n] * c->clean[k + j * c->n];
        c->rms[j] = sqrt(s2 / (double)c->n);
    }
    free(vals);
    free(cl);
    sim_engine_destroy(e);
    sim_config_free(&cfg);
}

static void capture_free(capture *c)
{
    free(c->clean);
    free(c->noisy);
    free(c->noisy_chan);
    free(c->rms);
    vibid_stand_destroy(c->stand);
}

/* noisy = clean + white Gaussian noise of std level x RMS(clean) on every measured
 * (non-input) channel, from the file's fixed xorshift stream. */
static void add_noise(capture *c, double level)
{
    for (size_t j = 0; j < c->nch; j++)
        for (size_t k = 0; k < c->n; k++)
            c->noisy[k + j * c->n] =
                c->clean[k + j * c->n] + (c->noisy_chan[j] && level > 0.0 ? level * c->rms[j] * normal() : 0.0);
}

#endif
