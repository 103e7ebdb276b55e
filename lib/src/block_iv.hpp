// block_iv.hpp: instrumental-variable regression (2.15) whose sums are kept per block of
// consecutive samples, so that the covariance of the estimate can be taken from the
// spread of the blocks' scores ("batch means") instead of assuming white equation
// errors. Used by identify.cpp for the automatic and the IV estimators.
//
// Why blocks: after central differences and the pre-filter the equation error is
// strongly coloured (a moving average over the stencil and the filter's memory, tens of
// samples). The textbook IV covariance sigma^2 (W^T X)^-1 (W^T W) (X^T W)^-1 assumes
// white errors and then claims a precision the data do not have (5 to 90 times too
// small in the issue that led here). With the data cut into K blocks much longer than
// the error's correlation, the block scores s_b = W_b^T (Y_b - X_b Theta) are nearly
// independent, and
//     Cov(vec Theta) = (I (x) A^-1) [sum_b vec(s_b) vec(s_b)^T / (1 - h_b)] (I (x) A^-T),
//     A = sum_b W_b^T X_b,  h_b = trace(W_b^T X_b A^-1) (the block's leverage),
// is consistent whatever the colour (a heteroscedasticity-and-autocorrelation-consistent
// estimate; dividing by 1 - h_b corrects for the directions fitted, K / (K - p) when the
// blocks are evenly informative, and keeps blocks that dominate the fit from hiding
// their own error).
//
// Two modes:
//  - forgetting = 1: all data count alike. K_max slots; when they are full, neighbouring
//    blocks are merged pairwise and the block length doubles, so between K_max / 2 and
//    K_max blocks are kept whatever the run length (fixed memory).
//  - forgetting gamma < 1: exponentially weighted sums (memory ~ 1 / (1 - gamma)
//    samples) in a ring of K_max blocks of fixed length covering about 6 memories; a
//    block's sums are discounted by gamma^(age) when the estimate is formed.
// The consistency check: the estimate from the older half of the blocks and from the
// newer half, each with its own covariance; z_i = (theta_old - theta_new)_i /
// sqrt(var_old + var_new). Both are consistent estimates of the same parameters, so
// |z| > 4 in any parameter (probability p * 6e-5 when the error bars hold) says that
// they do not: a change of the system inside the window, a bias that varies with the
// excitation, or a model that does not fit.
//
// Real time: add() allocates nothing and costs m (p^2 + p q + 2 p) multiply-adds, plus a
// merge of all blocks (K_max (p^2 + p q)) once per doubling; solve() allocates.
#pragma once

#include <Eigen/Dense>

#include <cstddef>
#include <vector>

namespace vibid {

struct BlockIVResult {
    Eigen::MatrixXd theta;   // p x q
    Eigen::MatrixXd cov;     // (p q) x (p q), vec column-major
    double rcond = 0.0;      // reciprocal condition of the scaled W^T X
    std::size_t rank = 0;
    std::size_t n_blocks = 0;
    double n_eff = 0.0;      // effective number of informative blocks (leverage-weighted; n_blocks when even)
    double z_max = 0.0;      // consistency check (NaN when it could not be made)
    std::vector<int> not_excited;  // p: 1 where the parameter lies in a direction with too little information
};

class BlockIV {
public:
    // p regressors, q outputs, gamma in (0, 1], block_len >= 1 samples at the start,
    // k_max >= 8 (even).
    BlockIV(std::size_t p, std::size_t q, double gamma, std::size_t block_len, std::size_t k_max);

    void reset();
    // n_rows equations: X, W n_rows x p, Y n_rows x q, column-major. Allocation-free.
    void add(std::size_t n_rows, const double *X, const double *W, const double *Y);
    // As add() with n_rows constant columns appended to X and W (the last n_rows of the p
    // regressors): column p - n_rows + r is -ux in row r and 0 elsewhere, its instrument
    // -uw (identify.cpp's constant forces, one per equation). X, W are n_rows x (p - n_rows).
    // The same sums as add() on the explicit columns, without their zeros: O(n_rows p)
    // more than add() on the leading columns instead of O(n_rows^2 p). Allocation-free.
    void add_constants(std::size_t n_rows, const double *X, const double *W, const double *Y, double ux, double uw);
    // Ends the current sample (block bookkeeping counts samples, not equations).
    void end_sample();

    unsigned long long samples() const { return samples_; }
    std::size_t blocks_with_data() const;

    // theta_ref (p x q, may be nullptr = 0): where a direction is hardly informed
    // (scaled singular value below 1e-7 of the largest: the excitation does not
    // separate some parameters in this window), the estimate keeps theta_ref's component
    // there and solves the informed directions only; those parameters are marked in
    // not_excited. Throws vibid::Error (VIBID_E_INSUFFICIENT_DATA when nothing is
    // informed at all). p_use (0 = all p): solve for the leading p_use regressors only,
    // with their own instruments, leaving the others out of the model (their sums are
    // kept: both fits come from the same sums); theta_ref then has p_use x q entries
    // (column stride p_use) and the result is p_use x q. consistency = false leaves out
    // the consistency check (z_max NaN; one solve instead of three).
    BlockIVResult solve(const double *theta_ref, std::size_t p_use = 0, bool consistency = true) const;

private:
    struct Block {
        Eigen::MatrixXd G;  // W^T X, p x p
        Eigen::MatrixXd c;  // W^T Y, p x q
        Eigen::VectorXd xx, ww;  // column sums of squares of X and W (for scaling)
        unsigned long long n = 0;  // samples
        unsigned long long end = 0;  // sample count at the block's last sample
    };
    void close_block();
    void merge_pairs();

    std::size_t p_, q_, k_max_;
    double gamma_;
    std::size_t block_len0_, block_len_;
    std::vector<Block> blocks_;  // k_max_ closed blocks (ring for gamma < 1)
    std::size_t n_closed_ = 0, head_ = 0;  // ring: head_ = oldest
    Block cur_;
    unsigned long long samples_ = 0;
    double cur_scale_ = 1.0;  // gamma^-j for sample j of the current block
};

}  // namespace vibid
