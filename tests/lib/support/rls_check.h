/* rls_check.h: matrix checks shared by the RLS tests (test_rls.c, test_rls_windup.c).
 * All matrices are column-major n x n or plain arrays of n values. */
#ifndef VIBID_RLS_CHECK_H
#define VIBID_RLS_CHECK_H
#include <stddef.h>

#include <vibid/rls.h>

/* 1 if the n x n matrix A passes a Cholesky factorisation of its upper triangle with
 * every pivot > 0 and finite (numerically positive definite), else 0. */
int rls_check_is_pd(const double *A, size_t n);

/* max_ij |A_ij - A_ji| / max_ij |A_ij| (0 for the zero matrix; NaN/Inf propagate). */
double rls_check_asymmetry(const double *A, size_t n);

/* max_i |a_i - b_i| / max_i |b_i|: relative difference of a against the reference b. */
double rls_check_rel_diff(const double *a, const double *b, size_t n);

/* Everything an RLS estimator exposes, to compare its state before and after a call
 * bit for bit. Sizes from the configuration; rls_snapshot_free releases the arrays. */
typedef struct rls_snapshot {
    size_t p, q;
    double *theta, *P, *sigma;
    int sigma_status;
    vibid_rls_stats stats;
} rls_snapshot;

void rls_snapshot_take(rls_snapshot *s, const vibid_rls *rls, size_t p, size_t q);
/* 1 if both snapshots are bit-identical. */
int rls_snapshot_equal(const rls_snapshot *a, const rls_snapshot *b);
void rls_snapshot_free(rls_snapshot *s);

#endif
