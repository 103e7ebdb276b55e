/* test_rng.h: reproducible random numbers for tests (same sequence on every machine).
 * xoshiro256** seeded by splitmix64; normals by the polar Box-Muller method. */
#ifndef VIBID_TEST_RNG_H
#define VIBID_TEST_RNG_H
#include <stddef.h>
#include <stdint.h>

typedef struct test_rng {
    uint64_t s[4];
    int has_spare;
    double spare;
} test_rng;

void test_rng_seed(test_rng *rng, uint64_t seed);
uint64_t test_rng_next(test_rng *rng);
/* Uniform in [0, 1). */
double test_rng_uniform(test_rng *rng);
/* Standard normal N(0, 1). */
double test_rng_normal(test_rng *rng);
/* v[0 .. n) = scale * N(0, 1) draws. */
void test_rng_fill_normal(test_rng *rng, double *v, size_t n, double scale);

#endif
