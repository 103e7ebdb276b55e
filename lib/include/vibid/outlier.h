/* vibid/outlier.h: single-sample glitches taken out before they reach an estimator.
 *
 * One wild value (a bit error, a sensor dropout that reads 1.0 or 1e300 for one sample)
 * in a capture of millimetre motions enters every sum of a least-squares or IV estimator;
 * without forgetting it stays there for the rest of the run. NaN is no such danger: the
 * estimators treat a non-finite value as a gap (vibid_ident_push restarts the regressor's
 * window). This object turns the glitch into exactly that: it passes samples through,
 * replacing a value that the signal's own history and its next sample show to be a
 * glitch by NaN, and counts it.
 *
 * The test, per channel c (values x_k in any unit; one detector per stream):
 *   S      the scale of the channel's recent motion: the largest increment |x_j - x_(j-1)|
 *          of the accepted values, held and decaying by exp(-1/memory) per sample (so the
 *          peak of the last ~memory samples). A peak, not a standard deviation: a held
 *          input (PRBS, a held base) that jumps rarely keeps its jumps in S.
 *   floor  max(q, 1e-6 |x_ref|): q the smallest non-zero jump seen so far (a quantised
 *          channel's step), 1e-6 of the level covers float32 rounding. S below the floor
 *          is taken as the floor.
 *   a sample is SUSPECT when |a| = |x_k - x_ref| (x_ref: the last accepted value) exceeds
 *          K max(S, floor). Otherwise it is accepted at once: a clean stream is passed
 *          through sample by sample, bit for bit, without delay.
 *   a suspect is an OUTLIER when its successors show it came back: with b = x_(k+1) - x_k
 *          and m = max(|x_(k+1) - x_ref|, |x_(k+2) - x_(k+1)|, |x_(k+3) - x_(k+2)|),
 *              min(|a|, |b|) > K max(S, floor, m),
 *          i.e. it jumped away by more than K times the recent motion, came back by as
 *          much, and the samples around it lie close together and stay quiet. A jump that
 *          stays (a held input's step, a new excitation level, the start of excitation of
 *          a stand at rest) or a signal that goes on moving that much (a random held input
 *          starting from rest) is accepted, up to VIBID_OUTLIER_LOOKAHEAD = 3 samples late.
 *          A suspect whose next value is missing (a gap, the end of the data) cannot be
 *          checked and is taken out ("unverified"); a later missing value shortens m.
 *   K      `threshold`, default 8 (VIBID_OUTLIER_THRESHOLD_DEFAULT).
 * The first `warmup` samples (default 16) have no history: they are held and decided
 * together, with S from the third-largest of their increments (one glitch makes two) and q
 * from the smallest, and the first value of each channel tested against its next two
 * (|x1 - x0| > K max(S, floor, |x2 - x1|)). The history (x_ref, S, q) is kept across
 * missing values and gaps: the first sample after a gap is tested against the last before.
 *
 * False outliers (tests/lib/test_outlier.c, tests/sim/test_outlier.c). On white Gaussian
 * noise S is the peak of ~memory increments (about 5 standard deviations), so a false
 * outlier needs a value some 40 standard deviations off both neighbours: none in 2 x 10^7
 * values. On 1.22 M values of vibid-sim captures (the shipped stands and simulations,
 * the paper's examples 1 and 2, force inputs held and smooth under every excitation
 * generator, measured as displacement, velocity, acceleration and force, from exact rest,
 * quantised): one, below. A smooth signal cannot make one: at an extremum min(|a|, |b|) <=
 * w^2 h^2 A / 2, while its increments reach w h A. What can:
 *   - the first one-step flicker of a quantised channel that rested exactly on one value
 *     since the start (no step seen in the warm-up): nothing tells it from a glitch; it
 *     teaches q, so it happens once per channel (the one in the captures above);
 *   - a held input of independent random values that starts from exact rest: its first
 *     value can look like a pulse (3000 starts: 2 with 60 dB measurement noise, 0 without;
 *     with one successor instead of three it was 17 of 200);
 *   - a legitimate single-sample pulse more than K times every increment of the last
 *     ~memory samples (a one-sample hammer blow after a long rest).
 * What is not taken out: a glitch longer than one sample (a level that holds is a step), a
 * glitch smaller than K times the recent motion (which also does little harm), a glitch
 * within 3 samples before another glitch, and in a channel that never moved, a glitch up
 * to K times the size of an earlier one (its jump taught q).
 *
 * Real time: every array is allocated in create. push, flush and released allocate
 * nothing and never throw; a push costs O(n_channels) (the warm-up's end
 * O(warmup n_channels), once): push and released of a clean 3-channel sample about 21 ns
 * (a loop of 5 * 10^6 pushes on one core of the 2-core test machine, under load).
 */
#ifndef VIBID_OUTLIER_H
#define VIBID_OUTLIER_H

#include <stddef.h>
#include <stdint.h>

#include <vibid/common.h>

#ifdef __cplusplus
extern "C" {
#endif

#define VIBID_OUTLIER_THRESHOLD_DEFAULT 8.0
#define VIBID_OUTLIER_MEMORY_DEFAULT 2048.0
#define VIBID_OUTLIER_WARMUP_DEFAULT 16
#define VIBID_OUTLIER_MAX_WARMUP 1024
#define VIBID_OUTLIER_LOOKAHEAD 3

typedef struct vibid_outlier vibid_outlier;

typedef struct vibid_outlier_config {
    size_t n_channels; /* values per sample, >= 1 */
    double threshold;  /* K above, >= 2 (default 8) */
    double memory;     /* decay time of the motion scale S in samples, >= 1 (default 2048) */
    size_t warmup;     /* samples decided together at the start, 4 .. VIBID_OUTLIER_MAX_WARMUP
                          (default 16) */
} vibid_outlier_config;

/* Counters since create or reset. */
typedef struct vibid_outlier_stats {
    uint64_t samples;         /* samples pushed */
    uint64_t outlier_samples; /* released samples with at least one value taken out */
    uint64_t outlier_values;  /* values taken out */
    uint64_t unverified;      /* of those, suspects whose next value was missing (gap, end) */
    uint64_t held;            /* suspect values that waited for their successors, incl. those
                                 found legitimate */
} vibid_outlier_stats;

/* Defaults for n_channels channels. cfg may not be NULL (nothing happens if it is). */
VIBID_API void vibid_outlier_config_init(vibid_outlier_config *cfg, size_t n_channels);

/* NULL on a bad configuration (vibid_last_error names the field) or out of memory. */
VIBID_API vibid_outlier *vibid_outlier_create(const vibid_outlier_config *cfg);
/* Back to the state after create: history, held samples and counters dropped. */
VIBID_API vibid_status vibid_outlier_reset(vibid_outlier *det);
VIBID_API void vibid_outlier_destroy(vibid_outlier *det);

/* Feeds the next sample: n_channels values; NaN or Inf = that value is missing (a sample
 * of all NaN stands for a gap). *n_released = the number of samples this call releases,
 * oldest first, in the order they were pushed: 0 while a suspect waits for its successors
 * or the warm-up collects, 1 usually, up to max(warmup, VIBID_OUTLIER_LOOKAHEAD + 1) at
 * once (the most that is ever held). Read them with
 * vibid_outlier_released before the next push or flush (which drop them). Every pushed
 * sample is released exactly once. VIBID_E_NULL_ARGUMENT only (nothing changes then). */
VIBID_API vibid_status vibid_outlier_push(vibid_outlier *det, const double *values, size_t *n_released);

/* The end of the data: everything still held is decided with the successors there are
 * and released (*n_released of them). The history is kept (a push may follow). */
VIBID_API vibid_status vibid_outlier_flush(vibid_outlier *det, size_t *n_released);

/* Released sample i (0 = oldest of the last push/flush): its values, with every outlier
 * replaced by NaN, into values_out (n_channels; may be NULL), and per channel 1 where the
 * value was taken out, else 0, into outlier_out (n_channels; may be NULL). *n_outliers (may
 * be NULL) = the number of values taken out. VIBID_E_OUT_OF_RANGE if i is not below the
 * last *n_released. */
VIBID_API vibid_status vibid_outlier_released(const vibid_outlier *det, size_t i, double *values_out,
                                              unsigned char *outlier_out, size_t *n_outliers);

VIBID_API vibid_status vibid_outlier_get_stats(const vibid_outlier *det, vibid_outlier_stats *stats);

#ifdef __cplusplus
}
#endif
#endif
