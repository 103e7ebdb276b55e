// discretize_internal.hpp: the Eigen-level functions behind discretize.h, used by
// identify.cpp for the ZOH way back (never installed). All throw vibid::Error.
#pragma once

#include <vibid/discretize.h>

#include <Eigen/Dense>

namespace vibid {

// G = e^{A h}, Gamma = int_0^h e^{A t} dt Bv (augmented exponential).
void zoh(const Eigen::MatrixXd &A, const Eigen::MatrixXd &Bv, double h, Eigen::MatrixXd &G, Eigen::MatrixXd &Gamma);

// Inverse of zoh via the real principal logarithm; throws VIBID_E_NUMERICAL when there
// is no real logarithm.
void zoh_inverse(const Eigen::MatrixXd &G, const Eigen::MatrixXd &Gamma, double h, Eigen::MatrixXd &A,
                 Eigen::MatrixXd &Bv, vibid_log_info &info);

// (1.16) with M~ = I from continuous M, D, C, Bv.
void second_order_form(const Eigen::MatrixXd &M, const Eigen::MatrixXd &D, const Eigen::MatrixXd &C,
                       const Eigen::MatrixXd &Bv, double h, Eigen::MatrixXd &Dt, Eigen::MatrixXd &Ct,
                       Eigen::MatrixXd &B1t, Eigen::MatrixXd &B2t);

// Way back: (1.16) -> K = M^-1 C, L = M^-1 D, J = M^-1 Bv.
void second_order_to_continuous(const Eigen::MatrixXd &Dt, const Eigen::MatrixXd &Ct, const Eigen::MatrixXd &B1t,
                                const Eigen::MatrixXd &B2t, double h, Eigen::MatrixXd &K, Eigen::MatrixXd &L,
                                Eigen::MatrixXd &J, vibid_log_info &info);

}  // namespace vibid
