/* lib.test_oma: output-only modal identification (vibid/oma.h) on simulated ambient
 * captures: a chain of masses excited by unmeasured white forces on every node (held over
 * each sample, so the simulation is the exact discretisation, vibid_zoh), its
 * displacements measured with 1 % sensor noise. The truth: vibid_modal of the same
 * matrices.
 *
 *  accuracy   3-DOF chain, 12 captures of 1800 s at 200 Hz: every mode found and no other,
 *             mean absolute errors of the frequencies within 0.1 % and of the damping
 *             ratios within 10 % (the figures for well-excited modes), every
 *             estimate within 4 of its standard errors. (A mean, not one capture: the first
 *             mode's damping, 0.73 %, has a standard error of 5 % of itself from 1800 s.)
 *  coverage   the same chain, 100 captures of 120 s: the share of 2-se intervals that hold
 *             the truth, per mode, for frequency and damping (first-order perturbation,
 *             oma.h 4.): pooled over the 600 intervals within 91..98 % (the issue asks
 *             90-98 %; the binomial standard deviation at 95 % is 0.9 %), each of the six
 *             at least 85 % (4 of its binomial standard deviations of 2.2 % below 95 %), and
 *             the mean standard error within a factor 1.5 of the RMS error. (400 captures
 *             gave 92-95 % for each of the six.)
 *  streaming  push and push_block give the same sums; a gap restarts the lag ring; the
 *             window keeps the last max_blocks blocks.
 *  chunked    push_block (matrix products per run of finite samples) in pieces of any
 *             size, with gaps at block boundaries, equals the per-sample path to rounding.
 *  chunked    push_block in pieces of any size (1 sample, a block, across blocks), with
 *             gaps and a subset of references, gives the per-sample path's results.
 *  refusals   configurations that cannot work, named. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

#include <vibid/discretize.h>
#include <vibid/modal.h>
#include <vibid/oma.h>

#include "test_rng.h"

#define NDOF 3

/* The sanitizer suite (scripts/test.sh: ASan + UBSan, -O1, Eigen's assertions on) runs the
 * same code paths 13 times slower: there the Monte Carlo studies run 2 and 10 captures
 * (memory and undefined-behaviour errors do not depend on the count) and their statistical
 * bounds (means over captures, coverage shares) are checked in the optimised suite only;
 * every per-estimate check stays. */
#if defined(__SANITIZE_ADDRESS__)
#define SANITIZED 1
#else
#define SANITIZED 0
#endif

static test_rng rng_state;
static double normal(void) { return test_rng_normal(&rng_state); }

/* The chain ground - m1 - m2 - m3: masses 1, 1.5, 1 kg, springs 1e4, 8e3, 6e3 N/m, dampers
 * 4, 3, 2 N s/m beside them. Modes about 8.3, 16.6, 25.6 Hz, 0.6-2.3 % damping. */
typedef struct chain {
    double M[NDOF * NDOF], D[NDOF * NDOF], K[NDOF * NDOF];
    double G[4 * NDOF * NDOF], Gam[2 * NDOF * NDOF];
    double f[NDOF], zeta[NDOF];
    double fs;
} chain;

static void chain_init(chain *c, double fs)
{
    const double m[NDOF] = {1.0, 1.5, 1.0}, k[NDOF] = {1e4, 8e3, 6e3}, d[NDOF] = {4.0, 3.0, 2.0};
    memset(c, 0, sizeof *c);
    c->fs = fs;
    for (int j = 0; j < NDOF; j++) {
        c->M[j + NDOF * j] = m[j];
        /* element j joins node j - 1 (ground for j = 0) and node j */
        c->K[j + NDOF * j] += k[j];
        c->D[j + NDOF * j] += d[j];
        if (j > 0) {
            c->K[(j - 1) + NDOF * (j - 1)] += k[j];
            c->K[(j - 1) + NDOF * j] -= k[j];
            c->K[j + NDOF * (j - 1)] -= k[j];
            c->D[(j - 1) + NDOF * (j - 1)] += d[j];
            c->D[(j - 1) + NDOF * j] -= d[j];
            c->D[j + NDOF * (j - 1)] -= d[j];
        }
    }
    assert_int_equal(vibid_modal(NDOF, c->M, c->D, c->K, c->f, c->zeta, NULL, NULL), VIBID_OK);
    /* x' = A x + Bv w, x = [y; y'], A = [0 I; -M^-1 K, -M^-1 D], Bv = [0; M^-1] (M diagonal) */
    const int N = 2 * NDOF;
    double A[4 * NDOF * NDOF] = {0}, B[2 * NDOF * NDOF] = {0};
    for (int j = 0; j < NDOF; j++) {
        A[j + N * (NDOF + j)] = 1.0;
        for (int q = 0; q < NDOF; q++) {
            A[(NDOF + j) + N * q] = -c->K[j + NDOF * q] / m[j];
            A[(NDOF + j) + N * (NDOF + q)] = -c->D[j + NDOF * q] / m[j];
        }
        B[(NDOF + j) + N * j] = 1.0 / m[j];
    }
    assert_int_equal(vibid_zoh(N, NDOF, A, B, 1.0 / fs, c->G, c->Gam), VIBID_OK);
}

/* n samples of the three displacements (column-major n x 3) under unit white forces, with
 * sensor noise of 1 % of each channel's RMS; 2000 samples of run-in discarded. */
static double *chain_capture(const chain *c, size_t n)
{
    const int N = 2 * NDOF;
    double x[2 * NDOF] = {0}, xn[2 * NDOF], w[NDOF];
    double *y = malloc(n * NDOF * sizeof(double));
    assert_non_null(y);
    for (size_t t = 0; t < n + 2000; t++) {
        for (int j = 0; j < NDOF; j++) w[j] = normal();
        for (int a = 0; a < N; a++) {
            double s = 0.0;
            for (int b = 0; b < N; b++) s += c->G[a + N * b] * x[b];
            for (int b = 0; b < NDOF; b++) s += c->Gam[a + N * b] * w[b];
            xn[a] = s;
        }
        memcpy(x, xn, sizeof x);
        if (t >= 2000)
            for (int j = 0; j < NDOF; j++) y[(t - 2000) + n * j] = x[j];
    }
    for (int j = 0; j < NDOF; j++) {
        double s2 = 0.0;
        for (size_t t = 0; t < n; t++) s2 += y[t + n * j] * y[t + n * j];
        const double noise = 0.01 * sqrt(s2 / (double)n);
        for (size_t t = 0; t < n; t++) y[t + n * j] += noise * normal();
    }
    return y;
}

static vibid_oma *oma_for(const chain *c, size_t n, size_t blocks)
{
    vibid_oma_config cfg;
    vibid_oma_config_init(&cfg, c->fs, NDOF);
    cfg.block_rows = 20;
    cfg.block_samples = n / blocks;
    cfg.max_blocks = blocks;
    vibid_oma *o = vibid_oma_create(&cfg);
    if (!o) fail_msg("vibid_oma_create: %s", vibid_last_error());
    return o;
}

/* The selected mode nearest to each true one (within 5 %); -1 where none. */
static void match(const chain *c, const vibid_oma_mode *m, size_t nm, int *which)
{
    for (int j = 0; j < NDOF; j++) {
        which[j] = -1;
        double best = 0.05;
        for (size_t q = 0; q < nm; q++) {
            const double rel = fabs(m[q].freq_hz / c->f[j] - 1.0);
            if (rel < best) {
                best = rel;
                which[j] = (int)q;
            }
        }
    }
}

static void test_accuracy(void **state)
{
    (void)state;
    chain c;
    chain_init(&c, 200.0);
    const size_t n = 360000, runs = SANITIZED ? 2 : 12;
    double abs_f[NDOF] = {0}, abs_z[NDOF] = {0}, worst_z[NDOF] = {0};
    for (size_t r = 0; r < runs; r++) {
        double *y = chain_capture(&c, n);
        vibid_oma *o = oma_for(&c, n, 32);
        size_t gaps = 99;
        assert_int_equal(vibid_oma_push_block(o, n, y, n, &gaps), VIBID_OK);
        assert_int_equal(gaps, 0);
        assert_int_equal(vibid_oma_identify(o), VIBID_OK);
        vibid_oma_mode m[16];
        double re[16 * NDOF], im[16 * NDOF];
        size_t nm = 0;
        assert_int_equal(vibid_oma_get_modes(o, 16, &nm, m, re, im), VIBID_OK);
        if (r == 0) {
            printf("  first capture: %zu modes selected\n", nm);
            for (size_t q = 0; q < nm && q < 16; q++)
                printf("    f %9.5f +- %.5f Hz  zeta %.5f +- %.5f  mpc %.3f  order %zu  poles %zu\n", m[q].freq_hz,
                       m[q].freq_se, m[q].zeta, m[q].zeta_se, m[q].mpc, m[q].order, m[q].n_poles);
        }
        assert_int_equal(nm, NDOF);  /* no spurious mode from noise */
        int which[NDOF];
        match(&c, m, nm, which);
        for (int j = 0; j < NDOF; j++) {
            assert_true(which[j] >= 0);
            const vibid_oma_mode *p = &m[which[j]];
            abs_f[j] += fabs(p->freq_hz / c.f[j] - 1.0) / (double)runs;
            abs_z[j] += fabs(p->zeta / c.zeta[j] - 1.0) / (double)runs;
            worst_z[j] = fmax(worst_z[j], fabs(p->zeta - c.zeta[j]) / p->zeta_se);
            assert_true(fabs(p->freq_hz - c.f[j]) <= 4.0 * p->freq_se);
            assert_true(fabs(p->zeta - c.zeta[j]) <= 4.0 * p->zeta_se);
            assert_true(p->mpc > 0.95); /* nearly real shapes: light, nearly proportional damping */
            /* the shape of mode 1 of a chain: all in phase, largest at the free end */
            if (j == 0)
                for (int q = 0; q < NDOF; q++) assert_true(re[which[j] + 16 * q] > 0.2);
        }
        vibid_oma_destroy(o);
        free(y);
    }
    for (int j = 0; j < NDOF; j++) {
        printf("  mode %d: truth f %.5f Hz zeta %.5f; mean |error| f %.4f %%, zeta %.2f %% (largest %.2f se)\n", j + 1,
               c.f[j], c.zeta[j], 100 * abs_f[j], 100 * abs_z[j], worst_z[j]);
        if (SANITIZED) continue;
        assert_true(abs_f[j] <= 0.001);
        assert_true(abs_z[j] <= 0.10);
    }
}

static void test_coverage(void **state)
{
    (void)state;
    chain c;
    chain_init(&c, 200.0);
    const size_t n = 24000, runs = SANITIZED ? 10 : 100;
    size_t hit_f[NDOF] = {0}, hit_z[NDOF] = {0}, found[NDOF] = {0};
    double se_f[NDOF] = {0}, sq_f[NDOF] = {0}, se_z[NDOF] = {0}, sq_z[NDOF] = {0};
    size_t all_hits = 0, all_found = 0;
    for (size_t r = 0; r < runs; r++) {
        double *y = chain_capture(&c, n);
        vibid_oma *o = oma_for(&c, n, 32);
        assert_int_equal(vibid_oma_push_block(o, n, y, n, NULL), VIBID_OK);
        assert_int_equal(vibid_oma_identify(o), VIBID_OK);
        vibid_oma_mode m[16];
        size_t nm = 0;
        assert_int_equal(vibid_oma_get_modes(o, 16, &nm, m, NULL, NULL), VIBID_OK);
        int which[NDOF];
        match(&c, m, nm < 16 ? nm : 16, which);
        for (int j = 0; j < NDOF; j++) {
            if (which[j] < 0) continue;
            const vibid_oma_mode *p = &m[which[j]];
            found[j]++;
            hit_f[j] += fabs(p->freq_hz - c.f[j]) <= 2.0 * p->freq_se;
            hit_z[j] += fabs(p->zeta - c.zeta[j]) <= 2.0 * p->zeta_se;
            se_f[j] += p->freq_se;
            sq_f[j] += (p->freq_hz - c.f[j]) * (p->freq_hz - c.f[j]);
            se_z[j] += p->zeta_se;
            sq_z[j] += (p->zeta - c.zeta[j]) * (p->zeta - c.zeta[j]);
        }
        vibid_oma_destroy(o);
        free(y);
    }
    for (int j = 0; j < NDOF; j++) {
        const double k = (double)found[j];
        printf("  mode %d (%.2f Hz): found in %zu of %zu; 2-se coverage f %.0f %%, zeta %.0f %%; mean se / RMS error: "
               "f %.3f / %.3f %%, zeta %.3f / %.3f (of zeta)\n",
               j + 1, c.f[j], found[j], runs, 100.0 * (double)hit_f[j] / k, 100.0 * (double)hit_z[j] / k,
               100 * se_f[j] / k / c.f[j], 100 * sqrt(sq_f[j] / k) / c.f[j], se_z[j] / k / c.zeta[j],
               sqrt(sq_z[j] / k) / c.zeta[j]);
        if (SANITIZED) continue;
        assert_true(found[j] >= 95);
        assert_true(hit_f[j] >= 0.85 * k && hit_z[j] >= 0.85 * k);
        all_hits += hit_f[j] + hit_z[j];
        all_found += 2 * found[j];
        const double rf = se_f[j] / k / sqrt(sq_f[j] / k), rz = se_z[j] / k / sqrt(sq_z[j] / k);
        assert_true(rf > 1.0 / 1.5 && rf < 1.5);
        assert_true(rz > 1.0 / 1.5 && rz < 1.5);
    }
    if (SANITIZED) return;
    const double pooled = (double)all_hits / (double)all_found;
    printf("  pooled 2-se coverage over the 3 modes' frequencies and damping ratios: %.1f %%\n", 100 * pooled);
    assert_true(pooled >= 0.91 && pooled <= 0.98);
}

/* push and push_block accumulate the same sums; a gap restarts the lag ring (no product
 * spans it) and is counted; the window keeps the last max_blocks blocks. */
static void test_streaming(void **state)
{
    (void)state;
    chain c;
    chain_init(&c, 200.0);
    const size_t n = 24000;
    double *y = chain_capture(&c, n);
    vibid_oma *a = oma_for(&c, n, 32), *b = oma_for(&c, n, 32);
    assert_int_equal(vibid_oma_push_block(a, n, y, n, NULL), VIBID_OK);
    double s[NDOF];
    for (size_t t = 0; t < n; t++) {
        for (int j = 0; j < NDOF; j++) s[j] = y[t + n * j];
        assert_int_equal(vibid_oma_push(b, s), VIBID_OK);
    }
    assert_int_equal(vibid_oma_identify(a), VIBID_OK);
    assert_int_equal(vibid_oma_identify(b), VIBID_OK);
    double sva[64], svb[64];
    size_t na = 0, nb = 0;
    assert_int_equal(vibid_oma_get_singular_values(a, 64, &na, sva), VIBID_OK);
    assert_int_equal(vibid_oma_get_singular_values(b, 64, &nb, svb), VIBID_OK);
    assert_int_equal(na, 60); /* min(20 x 3, 20 x 3) */
    assert_int_equal(na, nb);
    for (size_t j = 0; j < na; j++) assert_true(fabs(sva[j] - svb[j]) <= 1e-12 * sva[0]);
    /* a gap: counted, refused as a sample, and the same as two separate runs' sums */
    s[1] = NAN;
    assert_int_equal(vibid_oma_push(b, s), VIBID_E_NONFINITE);
    vibid_oma_stats st;
    assert_int_equal(vibid_oma_get_stats(b, &st), VIBID_OK);
    assert_int_equal(st.n_samples, n + 1);
    assert_int_equal(st.n_gaps, 1);
    assert_int_equal(st.blocks_complete, 32);
    /* the window: 32 more blocks replace the first 32 entirely: the result is that of
     * the second capture alone (a fresh object fed only with it) */
    double *y2 = chain_capture(&c, n);
    vibid_oma *fresh = oma_for(&c, n, 32);
    assert_int_equal(vibid_oma_reset(b), VIBID_OK);
    assert_int_equal(vibid_oma_push_block(b, n, y, n, NULL), VIBID_OK);
    assert_int_equal(vibid_oma_push_block(b, n, y2, n, NULL), VIBID_OK);
    assert_int_equal(vibid_oma_push_block(fresh, n, y2, n, NULL), VIBID_OK);
    assert_int_equal(vibid_oma_identify(b), VIBID_OK);
    assert_int_equal(vibid_oma_identify(fresh), VIBID_OK);
    assert_int_equal(vibid_oma_get_singular_values(b, 64, &na, sva), VIBID_OK);
    assert_int_equal(vibid_oma_get_singular_values(fresh, 64, &nb, svb), VIBID_OK);
    /* not bit-equal: the first block of b has products with the last samples of y (the
     * lag ring spans the boundary): up to 39 of 24000 products per lag (0.16 %) */
    double worst = 0.0;
    for (size_t j = 0; j < 6; j++) worst = fmax(worst, fabs(sva[j] / svb[j] - 1.0));
    printf("  window after 64 blocks against the last 32 alone: first 6 singular values within %.2e\n", worst);
    assert_true(worst <= 5e-3); /* measured 2.0e-3 */
    vibid_oma_destroy(a);
    vibid_oma_destroy(b);
    vibid_oma_destroy(fresh);
    free(y);
    free(y2);
}

/* push_block in pieces of any size gives the per-sample path's sums (to rounding): pieces
 * of 1, 7, 1000 samples, of a block, of a block and one, and a mixed pattern, over a capture
 * with gaps at the start, at the end, at and beside block boundaries, of one sample and of
 * more than the 39 lags, with two of the three channels as references (in reverse order),
 * over more blocks than the window holds. Each against vibid_oma_push sample by sample:
 * the counts exactly, every singular value within 1e-12 of the largest, and the selected
 * modes' frequencies and damping ratios within 1e-12 relative. */
static void test_chunked(void **state)
{
    (void)state;
    chain c;
    chain_init(&c, 200.0);
    const size_t n = 24000, block = 600;
    double *y = chain_capture(&c, n);
    /* gaps: the first sample, the last, a block boundary's both sides (block 5 ends at
     * 3000), one inside a block, 50 in a row (> 39 lags), one 2 after a block's start */
    const size_t lone[] = {0, n - 1, 2999, 3000, 7777, 9002};
    for (size_t g = 0; g < sizeof lone / sizeof lone[0]; g++) y[lone[g] + n * (g % NDOF)] = NAN;
    for (size_t t = 12345; t < 12395; t++) y[t + n * 2] = INFINITY;
    const size_t expect_gaps = sizeof lone / sizeof lone[0] + 50;
    vibid_oma_config cfg;
    vibid_oma_config_init(&cfg, c.fs, NDOF);
    size_t refs[2] = {2, 0};
    cfg.n_refs = 2;
    cfg.refs = refs;
    cfg.block_rows = 20;
    cfg.block_samples = block;
    cfg.max_blocks = 32; /* 40 blocks pushed: the window slides */
    vibid_oma *ref = vibid_oma_create(&cfg);
    assert_non_null(ref);
    double s[NDOF];
    for (size_t t = 0; t < n; t++) {
        for (int j = 0; j < NDOF; j++) s[j] = y[t + n * j];
        const vibid_status st = vibid_oma_push(ref, s);
        assert_true(st == VIBID_OK || st == VIBID_E_NONFINITE);
    }
    assert_int_equal(vibid_oma_identify(ref), VIBID_OK);
    double svr[64], sv[64];
    size_t nsv = 0, nmr = 0, nm = 0;
    assert_int_equal(vibid_oma_get_singular_values(ref, 64, &nsv, svr), VIBID_OK);
    vibid_oma_mode mr[32], m[32];
    assert_int_equal(vibid_oma_get_modes(ref, 32, &nmr, mr, NULL, NULL), VIBID_OK);
    assert_true(nmr >= 3 && nmr <= 32);
    vibid_oma_stats str, st;
    assert_int_equal(vibid_oma_get_stats(ref, &str), VIBID_OK);
    assert_int_equal(str.n_gaps, expect_gaps);

    const size_t mixed[] = {1, 7, 1000, 3, 4101, 599, 2, 601, 39, 40};
    const size_t fixed[] = {1, 7, 1000, block, block + 1, 0 /* mixed */};
    double worst_sv = 0.0, worst_f = 0.0, worst_z = 0.0;
    for (size_t v = 0; v < sizeof fixed / sizeof fixed[0]; v++) {
        vibid_oma *o = vibid_oma_create(&cfg);
        assert_non_null(o);
        size_t t = 0, piece = 0, gaps = 0;
        while (t < n) {
            size_t len = fixed[v] ? fixed[v] : mixed[piece++ % (sizeof mixed / sizeof mixed[0])];
            if (len > n - t) len = n - t;
            size_t g = 99;
            assert_int_equal(vibid_oma_push_block(o, len, y + t, n, &g), VIBID_OK);
            gaps += g;
            t += len;
        }
        assert_int_equal(gaps, expect_gaps);
        assert_int_equal(vibid_oma_get_stats(o, &st), VIBID_OK);
        assert_int_equal(st.n_samples, str.n_samples);
        assert_int_equal(st.n_gaps, str.n_gaps);
        assert_int_equal(st.blocks_complete, str.blocks_complete);
        assert_int_equal(vibid_oma_identify(o), VIBID_OK);
        assert_int_equal(vibid_oma_get_singular_values(o, 64, &nsv, sv), VIBID_OK);
        for (size_t j = 0; j < nsv; j++) worst_sv = fmax(worst_sv, fabs(sv[j] - svr[j]) / svr[0]);
        assert_int_equal(vibid_oma_get_modes(o, 32, &nm, m, NULL, NULL), VIBID_OK);
        assert_int_equal(nm, nmr);
        for (size_t q = 0; q < nm; q++) {
            assert_int_equal(m[q].order, mr[q].order);
            worst_f = fmax(worst_f, fabs(m[q].freq_hz / mr[q].freq_hz - 1.0));
            worst_z = fmax(worst_z, fabs(m[q].zeta / mr[q].zeta - 1.0));
        }
        vibid_oma_destroy(o);
    }
    printf("  %zu modes; push_block in pieces against push: singular values within %.1e of the largest, "
           "frequencies within %.1e, damping ratios within %.1e (relative)\n",
           nmr, worst_sv, worst_f, worst_z);
    assert_true(worst_sv <= 1e-12);
    assert_true(worst_f <= 1e-12);
    assert_true(worst_z <= 1e-10); /* measured 6.8e-13: the damping ratio is the most sensitive */
    vibid_oma_destroy(ref);
    free(y);
}

static void refused(vibid_oma_config *cfg, const char *what)
{
    assert_null(vibid_oma_create(cfg));
    printf("  refused: %s\n", vibid_last_error());
    assert_non_null(strstr(vibid_last_error(), what));
}

static void test_refusals(void **state)
{
    (void)state;
    vibid_oma_config cfg;
    vibid_oma_config_init(&cfg, 100.0, 2);
    refused(&cfg, "block_samples = 0");
    cfg.block_samples = 1000;
    cfg.block_rows = 1;
    refused(&cfg, "block_rows = 1");
    cfg.block_rows = 20;
    cfg.max_order = 7;
    refused(&cfg, "max_order = 7 must be even");
    cfg.max_order = 0;
    size_t refs[2] = {1, 1};
    cfg.n_refs = 2;
    cfg.refs = refs;
    refused(&cfg, "refs[1] repeats channel 1");
    cfg.n_refs = 0;
    cfg.refs = NULL;
    cfg.sample_rate = NAN;
    refused(&cfg, "sample_rate = nan");
    vibid_oma_config_init(&cfg, 100.0, 1);
    cfg.block_rows = 2;
    cfg.block_samples = 100;
    refused(&cfg, "allows no model order");
    /* no complete block: said, with the count */
    vibid_oma_config_init(&cfg, 100.0, 2);
    cfg.block_samples = 1000;
    vibid_oma *o = vibid_oma_create(&cfg);
    assert_non_null(o);
    size_t n = 0;
    assert_int_equal(vibid_oma_get_modes(o, 0, &n, NULL, NULL, NULL), VIBID_E_STATE);
    assert_int_equal(vibid_oma_identify(o), VIBID_E_INSUFFICIENT_DATA);
    assert_non_null(strstr(vibid_last_error(), "no complete block of 1000 samples"));
    vibid_oma_destroy(o);
}

int main(void)
{
    test_rng_seed(&rng_state, 20261129);
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_accuracy),
        cmocka_unit_test(test_coverage),
        cmocka_unit_test(test_streaming),
        cmocka_unit_test(test_chunked),
        cmocka_unit_test(test_refusals),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
