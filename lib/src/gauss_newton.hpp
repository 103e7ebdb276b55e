// gauss_newton.hpp: the Levenberg-Marquardt iteration, the sandwich covariance and the
// physical bounds shared by the output-error and the prediction-error fits
// (vibid/output_error.h; never installed).
#pragma once

#include "model_internal.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

namespace vibid {

constexpr double kGnPredictedDecreaseTol = 1e-8;  // cost units (half chi^2): within 1e-4 se of the optimum
constexpr double kGnSingularRcond = 1e-12;        // of the Jacobi-scaled information

// One fit's outcome: the unknowns phi at the end, their cost, why it is not an estimate
// (VIBID_OE_* bits), the steps taken, which start it came from, the covariance, the
// information's reciprocal condition and the names behind a singular direction or a bound.
struct FitState {
    Eigen::VectorXd phi;
    double cost = std::numeric_limits<double>::infinity();
    unsigned failure = 0, iterations = 0;
    std::size_t start = 0;
    Eigen::MatrixXd cov;
    double rcond = 0.0;
    std::string weak;
};

struct LmOutcome {
    bool converged = false;
    unsigned iterations = 0;  // accepted and rejected steps
};

// Levenberg-Marquardt on the Jacobi-scaled information from phi (its cost and derivative
// pass in cur on entry; both updated to the end point). eval(phi, with_derivatives, pass)
// returns the cost (inf where it cannot be evaluated) and, with derivatives, fills
// pass.H (np x np information, symmetric) and pass.g (minus the cost's gradient);
// project(phi) puts phi back inside its bounds. Converged when the Gauss-Newton model
// predicts a decrease below kGnPredictedDecreaseTol, or when not even a step of 1e-8 of the
// Gauss-Newton scale lowers the cost (a minimum to the precision of the evaluation).
template <class Pass, class Eval, class Project>
LmOutcome levenberg_marquardt(Eigen::VectorXd &phi, double &cost, Pass &cur, unsigned max_iterations, Eval &&eval,
                              Project &&project) {
    using Eigen::Index;
    const Index np = phi.size();
    Pass trial;
    double lambda = 1e-3;
    LmOutcome out;
    for (; out.iterations < max_iterations; ++out.iterations) {
        Eigen::VectorXd D = cur.H.diagonal().cwiseMax(0.0).cwiseSqrt();
        for (Index i = 0; i < np; ++i) D(i) = D(i) > 0 ? 1.0 / D(i) : 1.0;
        const Eigen::MatrixXd Hs = D.asDiagonal() * cur.H * D.asDiagonal();
        const Eigen::VectorXd gs = D.asDiagonal() * cur.g;
        Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(Hs);
        const Eigen::VectorXd lam = es.eigenvalues();
        const double lmax = lam.maxCoeff();
        const Eigen::VectorXd c = es.eigenvectors().transpose() * gs;
        double decrement = 0.0;
        for (Index i = 0; i < np; ++i)
            if (lam(i) > kGnSingularRcond * lmax) decrement += 0.5 * c(i) * c(i) / lam(i);
        if (decrement < kGnPredictedDecreaseTol) {
            out.converged = true;
            break;
        }
        Eigen::VectorXd ds = Eigen::VectorXd::Zero(np);
        for (Index i = 0; i < np; ++i)
            if (lam(i) > kGnSingularRcond * lmax) ds += es.eigenvectors().col(i) * (c(i) / (lam(i) + lambda));
        Eigen::VectorXd cand = phi + D.asDiagonal() * ds;
        project(cand);
        const double c_trial = eval(cand, false, trial);
        if (std::isfinite(c_trial) && c_trial < cost) {
            phi = cand;
            cost = eval(cand, true, cur);
            lambda = std::max(lambda / 3.0, 1e-12);
        } else {
            lambda *= 4.0;
            if (lambda > 1e8) {
                out.converged = true;
                break;
            }
        }
    }
    return out;
}

// The sandwich covariance H^-1 G H^-1 of an M-estimate: H its information (np x np), G
// the covariance of its score over blocks of consecutive samples (scores: np x B block
// sums, B >= 2), so that coloured residuals and model error widen the error bars. The
// inverse is taken in the Jacobi-scaled eigenbasis, dropping directions below
// kGnSingularRcond of the largest; those directions make the parameters they involve
// (weakest component > 0.3) infinitely uncertain.
struct Sandwich {
    Eigen::MatrixXd cov;      // np x np
    Eigen::MatrixXd Hinv;     // the information's (pseudo-)inverse
    double rcond = 0.0;       // reciprocal condition of the scaled information
    bool singular = false;    // rcond < kGnSingularRcond
    Eigen::VectorXd weakest;  // the scaled information's eigenvector of the smallest eigenvalue
};

inline Sandwich sandwich(const Eigen::MatrixXd &H, const Eigen::MatrixXd &scores) {
    using Eigen::Index;
    const Index np = H.rows();
    Sandwich s;
    Eigen::VectorXd D = H.diagonal().cwiseMax(0.0).cwiseSqrt();
    for (Index i = 0; i < np; ++i) D(i) = D(i) > 0 ? 1.0 / D(i) : 1.0;
    const Eigen::MatrixXd Hs = D.asDiagonal() * H * D.asDiagonal();
    Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(Hs);
    const Eigen::VectorXd lam = es.eigenvalues();
    const double lmax = lam.maxCoeff();
    s.rcond = lmax > 0 ? std::max(0.0, lam.minCoeff()) / lmax : 0.0;
    s.singular = s.rcond < kGnSingularRcond;
    s.weakest = es.eigenvectors().col(0);
    s.Hinv = Eigen::MatrixXd::Zero(np, np);
    for (Index i = 0; i < np; ++i)
        if (lam(i) > kGnSingularRcond * lmax) s.Hinv += es.eigenvectors().col(i) * es.eigenvectors().col(i).transpose() / lam(i);
    s.Hinv = D.asDiagonal() * s.Hinv * D.asDiagonal();
    const Index B = scores.cols();
    const Eigen::VectorXd mean = scores.rowwise().mean();
    const Eigen::MatrixXd c = scores.colwise() - mean;
    const Eigen::MatrixXd G = (c * c.transpose()) * (static_cast<double>(B) / static_cast<double>(std::max<Index>(B - 1, 1)));
    s.cov = s.Hinv * G * s.Hinv;
    if (s.singular)
        for (Index i = 0; i < np; ++i)
            if (std::fabs(s.weakest(i)) > 0.3) s.cov(i, i) = std::numeric_limits<double>::infinity();
    return s;
}

// The physical bounds of a model's unknowns: masses > 0 (strictly: above 1e-9 of their
// start), springs and dampers >= 0 in a network model (a full-matrix model's entries may be
// negative), anything else free; and the unknowns' names.
struct PhysicalBounds {
    explicit PhysicalBounds(const vibid_model &model) {
        for (std::size_t i = 0; i < model.param_term.size(); ++i) {
            const auto &t = model.terms[model.param_term[i]];
            const bool spring_or_damper = t.kind == VIBID_PARAM_DAMPING || t.kind == VIBID_PARAM_STIFFNESS;
            is_mass.push_back(t.kind == VIBID_PARAM_MASS);
            lower.push_back(t.kind == VIBID_PARAM_MASS || (spring_or_damper && !model.full_matrix)
                                ? 0.0
                                : -std::numeric_limits<double>::infinity());
            names.push_back(t.name);
        }
    }
    // Puts the first p entries of phi (the unknowns) inside the bounds; start: the fit's start.
    void project(Eigen::VectorXd &phi, const Eigen::VectorXd &start) const {
        for (std::size_t i = 0; i < lower.size(); ++i) {
            const Eigen::Index k = static_cast<Eigen::Index>(i);
            phi(k) = std::max(phi(k), is_mass[i] ? 1e-9 * std::fabs(start(k)) : lower[i]);
        }
    }
    // The names of the unknowns on their bound ("'a', 'b'"; "" for none).
    std::string at_bound(const Eigen::VectorXd &phi, const Eigen::VectorXd &start) const {
        std::string out;
        for (std::size_t i = 0; i < lower.size(); ++i) {
            const Eigen::Index k = static_cast<Eigen::Index>(i);
            const bool at = is_mass[i] ? phi(k) <= 1e-9 * std::fabs(start(k)) * (1 + 1e-12)
                                       : (std::isfinite(lower[i]) && phi(k) <= lower[i]);
            if (at) out += (out.empty() ? "'" : ", '") + names[i] + "'";
        }
        return out;
    }
    std::vector<bool> is_mass;
    std::vector<double> lower;
    std::vector<std::string> names;
};

}  // namespace vibid
