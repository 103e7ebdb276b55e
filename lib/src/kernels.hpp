// kernels.hpp: the hot inner loops of the recursive and batch least-squares estimators
// (rls.cpp, lsq.cpp) and of the per-sample regressor (regressor.cpp), behind a table of
// function pointers chosen once per process.
//
// Why a table: the library is built for baseline x86-64 (SSE2), but most machines it runs
// on have AVX2 and FMA, which double the width of the vector units and fuse the
// multiply-adds these loops consist of. The same source (kernels_impl.hpp) is compiled
// twice, once for the baseline and once with -mavx2 -mfma (kernels_avx2.cpp, x86-64
// only), and the table of the widest variant the CPU supports is used. Setting the
// environment variable VIBID_FORCE_BASELINE=1 (read once, at the first use) selects the
// baseline table, so that both paths can be tested on one machine. The kernels are
// free of Eigen on purpose: Eigen's inline functions compiled with AVX2 in one
// translation unit and without in another would be one symbol with two bodies, and the
// linker could hand the AVX2 body to a baseline caller.
//
// All kernels allocate nothing, take no lock and cost a fixed number of operations for
// given sizes; pointers are borrowed for the duration of the call only.
#pragma once

#include <cstddef>

namespace vibid {
namespace kern {

using idx = std::ptrdiff_t;

// One equation of a Bierman RLS update (rls.cpp), everything that is O(p^2) or O(p q) in
// one call: the a-priori error e = y - Theta^T x, the Bierman update of U and D (see
// Table::bierman_step), Theta_new = Theta + b e^T / alpha and V_new = vscale V +
// e e^T / alpha. Inputs are set by the caller, outputs by the kernel. Shapes: U p x p
// column-major with column stride ld, Theta p x q with column stride p, y q entries with
// stride ystride, V q x q. All pointers are borrowed for the call only.
// Table::bierman_small does all m equations of a sample in one call: x is then p x m
// (column stride p) and y m x 1, see there.
struct RlsStep {
    // inputs
    idx p, q, ld, ystride;
    idx m;              // equations of the sample (bierman_small only)
    const double *us;   // U read
    double *ud;         // U written (== us allowed)
    const double *ds;   // D read
    double *dd;         // D written (== ds allowed)
    double dscale;      // 1 / forgetting applied to D first (1 for later equations)
    const double *ths;  // Theta read
    double *thd;        // Theta written (== ths allowed)
    const double *x;    // regressor, p
    const double *y;    // targets, q
    const double *Vs;   // residual sum of squares read, q x q
    double *Vd;         // residual sum of squares written (== Vs allowed): vscale Vs + e e^T / alpha
    double vscale;      // forgetting applied to V first (1 for later equations)
    double *b;          // p scratch; on return P~ x
    double *e;          // q scratch; on return the a-priori error
    double *work;       // scratch, 2 p doubles
    // outputs
    double alpha;      // 1 + x^T P~ x
    double trace;      // trace of the new P
    double theta_sum;  // sum of the new Theta's entries (finiteness check: see axpy_sum)
    double v_sum;      // sum of the new V's entries (idem)
    bool ok;           // false: a new D entry or alpha not positive and finite, or the trace not finite
};

// A cubic entry of the compiled regressor (regressor.cpp): out[out] += coef r^3 with the
// relative displacement r = sum_t w[t] window[col[tap[t]]]. At most kCubicTaps taps: the
// displacements of both ends, each at most a five-point stencil.
constexpr idx kCubicTaps = 10;
struct RegCubic {
    idx out;      // index into RegStep::out
    double coef;  // entry coefficient (an unknown's column) or -value * coefficient (target)
    idx n_taps;
    idx tap[kCubicTaps];  // indices into RegStep::col
    double w[kCubicTaps];
};

// One sample of the compiled regressor (regressor.cpp): every regressor column and target
// entry of the central-difference structured form is a fixed linear combination of the
// window's sample values (stencils, hold equivalents, entry coefficients and known values
// folded in at create), except cubic entries (the cube of one). Then the optional pre-filter
// runs on every entry alike. out has n_pad entries: x's p m, then y's m q, then zeros up to
// a multiple of 4. Its entries come in blocks of four; block b reads the window values of
// columns block[b] .. block[b + 1] - 1, column k with the four weights A[4k .. 4k + 3] (one
// per entry of the block): a block-sparse matrix whose work grows with the stencils' taps.
struct RegStep {
    idx n_pad;             // entries of out, a multiple of 4
    bool linear;           // false: out is given (the ZOH form), filter only
    const double *A;       // 4 weights per column
    const idx *block;      // n_pad / 4 + 1 column offsets
    const double *window;  // the sample history (regressor.cpp's ring)
    const idx *col;        // window index of the value of each column (blocks', then cubic taps)
    idx n_cubic;
    const RegCubic *cubic;
    const double *sec;     // pre-filter: b0 b1 b2 a1 a2 of two biquads (a0 = 1), or nullptr = off
    double *z;             // filter delays, 4 x n_pad structure-of-arrays: z[s n_pad + i]
    double *out;           // n_pad
};

// Largest p that Table::bierman_small takes. Above it the per-equation step is as fast: p = 5
// and 6 gained 3-5 % with 2-3 equations but lost 10 % with one, and at p = 8 the state no
// longer stays in registers (40 % slower).
constexpr idx kSmallP = 4;

struct Table {
    const char *name;  // "baseline" or "avx2+fma"

    // One equation of a Bierman RLS update, see RlsStep: Bierman's UD measurement update
    // of P = U D U^T (U unit upper triangular, only its strict upper part read or
    // written) with unit measurement variance, after the forgetting step folded in as
    // D * dscale; b = P~ x with P~ = U (D dscale) U^T, alpha = 1 + x^T P~ x. In place
    // (ud == us, dd == ds, thd == ths, Vd == Vs) is safe: every entry is read before it is
    // overwritten and not read after.
    // Cost: p^2 / 2 multiply-adds for U^T x, 1.5 p^2 for the update of U, the gain and the
    // trace (one fused pass), p divisions, 2 p q + q^2 for e, Theta and V.
    void (*bierman_step)(RlsStep &s);

    // All m equations of one sample for p <= kSmallP and q = 1: the first as bierman_step
    // from the state (us, ds, ths, Vs) to the other one (ud, dd, thd, Vd), the later ones
    // as bierman_step in place on that with dscale = vscale = 1 (forgetting once per
    // sample); x p x m (column stride p), y m entries. Outputs as bierman_step's, of the last
    // equation, except ok, which is false if any equation failed (a failed equation does not
    // stop the later ones; their results are garbage). alpha, b, e and work are not used.
    void (*bierman_small)(RlsStep &s);

    // Merges a block of rows into the triangular factor of a QR factorisation:
    // [R; A] = Q [R'; 0] with R n x n upper triangular, row-major (R[i * n + j]), and
    // A b x n column-major with column stride lda >= b. R is overwritten with R' (its
    // diagonal kept >= 0, as Givens rotations would leave it), A is destroyed. One
    // Householder reflection per column, structured so that R's zeros below the diagonal
    // are never touched: 2 b n^2 flops, A read twice per column while it sits in cache
    // (the caller keeps b n small). Overflow- and underflow-safe norms (a scaled
    // fallback runs only when a sum of squares leaves [1e-280, 1e280]).
    void (*qr_merge)(idx n, double *R, idx b, double *A, idx lda);

    // a . b over n entries.
    double (*dot)(const double *a, const double *b, idx n);

    // y = x + c g over n entries (y == x allowed); returns the sum of the new y, which is
    // NaN or Inf when an entry is (or, rarely, when the sum alone overflows: callers
    // confirm a non-finite sum with an exact scan before refusing anything).
    double (*axpy_sum)(idx n, double c, const double *g, const double *x, double *y);

    // One sample of the compiled regressor, see RegStep: out = A v + cubic entries (if
    // linear), then out through the two biquads, each entry with its own delays (the same
    // direct-form-II-transposed arithmetic per entry as a scalar filter). Cost: 4
    // multiply-adds per block column, the cubic taps, 10 n_pad flops for the filter.
    void (*regressor_step)(const RegStep &s);
};

// The table in use: AVX2+FMA when the CPU has both (and the library was built with the
// variant), else the baseline; VIBID_FORCE_BASELINE=1 in the environment forces the
// baseline. Decided at the first call (thread-safe), the same for the whole process.
const Table &active();

// The baseline table, whatever the CPU (for tests and benchmarks).
const Table &baseline();

// Table definitions, one per compiled variant (kernels_base.cpp, kernels_avx2.cpp).
extern const Table baseline_table;
#if defined(VIBID_HAVE_AVX2_KERNELS)
extern const Table avx2_table;
#endif

}  // namespace kern
}  // namespace vibid
