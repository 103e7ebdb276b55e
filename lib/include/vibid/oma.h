/* vibid/oma.h: output-only modal identification. Covariance-driven stochastic subspace
 * identification (SSI-cov) of the modes of a structure excited by unmeasured, broadband
 * forces (ambient, operational), from its response channels alone, with the standard
 * errors of the frequencies and damping ratios.
 *
 * The method (Peeters & De Roeck 1999; uncertainty: Reynders, Pintelon & De Roeck 2008,
 * Doehler & Mevel 2013):
 * 1. Output covariances. R_k = E[y_(t+k) y_ref,t^T] (n_channels x n_refs) for the lags
 *    k = 1 .. 2 i - 1 (i = block_rows), accumulated per sample (vibid_oma_push: a ring of
 *    the last 2 i reference samples, allocation-free, O(2 i n_channels n_refs) per
 *    sample). The sums are kept per block of block_samples consecutive samples (each
 *    product belongs to the block of its later sample); the estimate uses the last
 *    max_blocks complete blocks (a sliding window in a monitoring run, the whole capture
 *    in a batch run where block_samples = n / max_blocks). A non-finite sample is a gap:
 *    no product spans it (the ring restarts; counted).
 * 2. The block Hankel matrix H (i n_channels x i n_refs), block (a, b) = R_(a+b+1), and
 *    its SVD H = U S V^T (once for every model order).
 * 3. Per model order n (even, 2 .. max_order): the observability matrix O = U_n S_n^(1/2);
 *    C its first block row; A = O_up^+ O_down (least squares, the shifted block rows); the
 *    eigenvalues lambda of A give the poles mu = fs ln(lambda), f = |mu| / 2 pi,
 *    zeta = -Re(mu) / |mu|, and the mode shape phi = C v (normalised to 1 at its largest
 *    component); one pole per complex-conjugate pair (Im lambda > 0) is kept; real poles
 *    are dropped.
 * 4. Standard errors of f and zeta by first-order perturbation: the covariance of vec(H)
 *    from the spread of the block Hankel matrices H_b of the nb blocks in the window,
 *    Sigma_H = sum_b (H_b - Hbar)(H_b - Hbar)^T / (nb (nb - 1)) (blocks long against the
 *    correlation time are nearly independent), and the sensitivity J of each pole's f and
 *    zeta to H: var(f) = sum_b (J (H_b - Hbar))^2 / (nb (nb - 1)). J is applied to the nb
 *    directions without forming it (Doehler & Mevel's multi-order scheme): the perturbed
 *    singular vectors from one SVD for all orders, then the perturbed A and eigenvalues
 *    per order (only the perturbation of the column space of O counts: a change of basis
 *    within it does not move the eigenvalues). Needs nb >= 2; more blocks give a better
 *    covariance (default 32 in the batch front ends; coverage measured in tests/lib/test_oma.c).
 * 5. Stabilisation diagram: a pole of order n is stable when a pole of order n - 2 has
 *    |df| / f <= stab_freq, |dzeta| <= stab_damping zeta and MAC >= stab_mac; where both
 *    poles' frequencies are determined within stab_freq (their standard errors) the damping
 *    may instead differ by up to twice the two poles' combined standard errors (a lightly
 *    damped mode over a short window, whose damping is uncertain by 100 % and more, is not
 *    lost to the relative test). It is physical when 0 < zeta <= max_damping and
 *    f < 0.9 x Nyquist.
 * 6. Automatic mode selection: the stable physical poles are sorted by frequency and cut
 *    into clusters where neighbours are more than cluster_freq apart (relative); within a
 *    cluster the poles whose MAC with the cluster's medoid (the pole of median frequency)
 *    is below cluster_mac are dropped. A cluster is a mode when it holds at least
 *    min_cluster_share of the evaluated orders (and at least 3 poles). Its values, shape
 *    and standard errors are those of one of its poles (stable or not: physical, in the
 *    cluster's frequency span widened by cluster_freq, MAC >= cluster_mac with the
 *    medoid): the one at the lowest order at or above n*, the lowest order at which the
 *    most modes have a pole, whose frequency and damping standard errors are within 1.2
 *    times the smallest of the mode's poles at or above n* (the nearest to the medoid's
 *    frequency if two). The first-order standard errors hold where the truncation falls
 *    between well-separated singular values and overstate the spread many times where it
 *    cuts into the noise floor; a model order below n* lacks modes, which biases the
 *    others; and a mode may need more order than n* where the excitation has dynamics of
 *    its own (oma.cpp, choose_representatives, has the figures). Modes are reported in
 *    order of frequency.
 *
 * Units: fs in Hz; f in Hz; zeta dimensionless (fraction of critical); mode shapes in the
 * channels' own units, relative. Channels of different kinds (acceleration beside
 * displacement) mix in the shapes; scale them to similar sizes for readable shapes (the
 * poles do not depend on the scaling).
 *
 * Threads: one object per thread; vibid_oma_push is real-time safe (no allocation, no
 * lock, O(2 i n_channels n_refs)); vibid_oma_identify allocates and takes
 * O((i n)^3 + nb max_order (i n)^2) (run it in a low-priority thread; vibidd does).
 */
#ifndef VIBID_OMA_H
#define VIBID_OMA_H

#include <stdint.h>

#include <vibid/common.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct vibid_oma vibid_oma;

typedef struct vibid_oma_config {
    double sample_rate;     /* Hz, finite, > 0 */
    size_t n_channels;      /* response channels per sample, 1..256 */
    size_t n_refs;          /* reference channels, 1..n_channels (0: all channels) */
    const size_t *refs;     /* their indices in the sample (n_refs, distinct; NULL: 0..n_refs-1);
                               copied at create */
    size_t block_rows;      /* i: Hankel of i x i blocks, lags 1..2i-1; 2..1024 */
    size_t max_order;       /* even, 2..min((i-1) n_channels, i n_refs) rounded down to even;
                               0: that bound, at most 100 */
    size_t block_samples;   /* samples per covariance block, >= 4 i */
    size_t max_blocks;      /* window: the last max_blocks complete blocks, 2..65536 */
    /* Stabilisation and selection (5., 6.); vibid_oma_config_init's defaults in brackets. */
    double stab_freq;         /* [0.01] */
    double stab_damping;      /* [0.05] */
    double stab_mac;          /* [0.98] */
    double max_damping;       /* [0.2] */
    double cluster_freq;      /* [0.01] */
    double cluster_mac;       /* [0.9] */
    double min_cluster_share; /* [0.3] */
} vibid_oma_config;

/* The defaults above; sample_rate, n_channels as given, n_refs 0 (all), block_rows 20,
 * max_order 0 (automatic), block_samples 0 and max_blocks 32 (block_samples must be set). */
VIBID_API void vibid_oma_config_init(vibid_oma_config *cfg, double sample_rate, size_t n_channels);

/* Checks cfg (VIBID_E_OUT_OF_RANGE / VIBID_E_DIMENSION naming the field) and sizes
 * everything the per-sample path needs. NULL on error (vibid_last_error says why). */
VIBID_API vibid_oma *vibid_oma_create(const vibid_oma_config *cfg);
VIBID_API void vibid_oma_destroy(vibid_oma *oma);

/* The settings in force (max_order resolved). */
VIBID_API vibid_status vibid_oma_get_config(const vibid_oma *oma, vibid_oma_config *cfg);

/* One sample (n_channels values, the channels' units). Allocation-free. A non-finite
 * value: VIBID_E_NONFINITE, the sample is a gap (nothing accumulated, the lag ring
 * restarts). */
VIBID_API vibid_status vibid_oma_push(vibid_oma *oma, const double *sample);

/* n samples, column-major (n x n_channels, column stride ld >= n): the same sums as n
 * pushes (to rounding), faster (matrix products per block). A non-finite value is a gap
 * as in vibid_oma_push; *n_gaps (may be NULL) receives how many samples were. */
VIBID_API vibid_status vibid_oma_push_block(vibid_oma *oma, size_t n, const double *data, size_t ld,
                                            size_t *n_gaps);

/* Forgets every sample. */
VIBID_API vibid_status vibid_oma_reset(vibid_oma *oma);

typedef struct vibid_oma_stats {
    uint64_t n_samples;      /* samples pushed (gaps included) */
    uint64_t n_gaps;         /* non-finite samples */
    size_t blocks_complete;  /* complete blocks in the window (<= max_blocks) */
} vibid_oma_stats;
VIBID_API vibid_status vibid_oma_get_stats(const vibid_oma *oma, vibid_oma_stats *stats);

/* One pole of the stabilisation diagram. */
typedef struct vibid_oma_pole {
    size_t order;          /* model order n */
    double freq_hz, freq_se;
    double zeta, zeta_se;  /* se NaN with fewer than 2 blocks */
    double mpc;            /* modal phase collinearity of its shape, 0..1 (1: real shape) */
    int stable;            /* 1: stable against order n - 2 (5.) */
    int physical;          /* 1: 0 < zeta <= max_damping, f < 0.9 Nyquist */
    long mode;             /* index of the selected mode whose cluster holds it, or -1 */
} vibid_oma_pole;

/* One selected mode (6.). */
typedef struct vibid_oma_mode {
    double freq_hz, freq_se;
    double zeta, zeta_se;
    double mpc;
    size_t order;      /* the order of the pole it is taken from */
    size_t n_poles;    /* poles in its cluster */
} vibid_oma_mode;

/* Runs the identification over the window's complete blocks (at least one;
 * VIBID_E_INSUFFICIENT_DATA before). The results stay in the object until the next call:
 * vibid_oma_get_modes, vibid_oma_get_poles. VIBID_E_NUMERICAL when the Hankel matrix is
 * zero (no response). Allocates. */
VIBID_API vibid_status vibid_oma_identify(vibid_oma *oma);

/* The selected modes of the last identification: *n_out their number; up to cap written
 * to modes, and their shapes to shape_re / shape_im (cap x n_channels, column-major
 * cap-stride: shape of mode j in rows j of columns 0..n_channels-1; each may be NULL).
 * VIBID_E_STATE before vibid_oma_identify. */
VIBID_API vibid_status vibid_oma_get_modes(const vibid_oma *oma, size_t cap, size_t *n_out, vibid_oma_mode *modes,
                                           double *shape_re, double *shape_im);

/* Every pole of the last identification, orders ascending, frequencies ascending within an
 * order: *n_out their number; up to cap written. VIBID_E_STATE before vibid_oma_identify. */
VIBID_API vibid_status vibid_oma_get_poles(const vibid_oma *oma, size_t cap, size_t *n_out, vibid_oma_pole *poles);

/* The singular values of the last identification's Hankel matrix (min(i n_channels,
 * i n_refs) of them, descending): *n_out their number, up to cap written. */
VIBID_API vibid_status vibid_oma_get_singular_values(const vibid_oma *oma, size_t cap, size_t *n_out, double *sv);

#ifdef __cplusplus
}
#endif
#endif
