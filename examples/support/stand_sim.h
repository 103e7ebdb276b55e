/* stand_sim.h: a small, accurate simulator for the paper's examples and the model tests
 * (the SUNDIALS simulator vibid-sim is the product one). It integrates
 *     M y'' = f(y, y', s, s', u)        (vibid_model_forces, vibid_model_assemble)
 * with classical RK4 and `substeps` steps per sample interval, and samples every channel
 * of the model's layout at t_k = k h.
 *
 * Base motion: a triangle wave s(t) of amplitude `base_amplitude` and frequency
 * `base_freq_hz` starting at 0 and rising (the paper's Bild 2 excitation). Force inputs:
 * u_j(t) = input_amplitude * sin(2 pi f_j t) with f_j = input_freq_hz * (1 + 0.37 j)
 * (distinct per input).
 * hold = 1: every input (base included) is held at its value at t_k over [t_k, t_k + h)
 * (the ZOH assumption (1.10); the discrete model (1.14) is then exact). hold = 0: the
 * input follows its continuous law (the triangle's corners fall on sample instants when
 * 1 / (2 base_freq_hz h) is an integer, so RK4 keeps its order).
 * Accuracy: RK4 error per step ~ (omega h / substeps)^5; with 20 substeps at 40 samples
 * per period of the highest mode, about 1e-10 relative over 20,000 samples.
 */
#ifndef STAND_SIM_H
#define STAND_SIM_H

#include <stddef.h>
#include <stdint.h>
#include <vibid/vibid.h>

#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif

typedef struct stand_sim_config {
    double h;               /* s */
    size_t n_samples;
    int substeps;           /* RK4 steps per sample, >= 1 */
    int hold;               /* see above */
    double base_amplitude;  /* m (or the model's length unit) */
    double base_freq_hz;
    double input_amplitude; /* input units */
    double input_freq_hz;
} stand_sim_config;

/* Simulates from rest. theta: true values of the unknowns (p), NULL = nominal.
 * channels: n_samples x n_channels, column-major (one column per channel).
 * Returns 0 on success, -1 on failure (message on stderr). */
int stand_sim_run(const vibid_model *model, const double *theta, const stand_sim_config *cfg, double *channels);

/* Adds white Gaussian noise of standard deviation rel * RMS(channel) to every column.
 * rng_state: any non-zero seed; advanced. */
void stand_sim_add_noise(double *channels, size_t n_samples, size_t n_channels, double rel, uint64_t *rng_state);

/* Standard normal from a xorshift64* state (polar Box-Muller, no spare kept). */
double stand_sim_normal(uint64_t *rng_state);

#endif
