// modal_work.hpp: the modal analysis of one model with its scratch allocated once
// (modal.cpp), so that the analysis at new parameter values allocates nothing: what a
// reported row (report.cpp) needs on vibidd's estimation thread. vibid_model_modal and
// vibid_modal (modal.h) run the same code on a work object of their own.
#ifndef VIBID_MODAL_WORK_HPP
#define VIBID_MODAL_WORK_HPP

#include <vibid/modal.h>

#include <Eigen/Dense>

#include <cstddef>
#include <utility>
#include <vector>

namespace vibid {

class ModalWork {
public:
    // For model (finalized; it must outlive the work): n = its nodes, p = its unknowns.
    explicit ModalWork(const vibid_model *model);
    // For vibid_modal's matrices (n x n each, no model): p = 0.
    explicit ModalWork(std::size_t n);

    // vibid_model_modal's contract (modal.h), allocating nothing: theta (p, NULL = nominal),
    // cov (p x p or NULL), the outputs as there. Returns VIBID_OK or VIBID_E_UNSTABLE (every
    // output written); throws vibid::Error for the other failures.
    vibid_status model_modal(const double *theta, const double *cov, double *freq_hz, double *freq_se, double *zeta,
                             double *zeta_se, double *shape_re, double *shape_im, const char *fn);
    // vibid_modal's: M, D (may be NULL), C n x n.
    vibid_status matrices_modal(const double *M, const double *D, const double *C, double *freq_hz, double *zeta,
                                double *shape_re, double *shape_im, const char *fn);

private:
    struct Mode {
        double freq_hz = 0.0, zeta = 0.0;
        // the eigenvalue(s) of the state matrix behind the mode: root (Im > 0) of an
        // oscillating pair, or the two real roots of an overdamped / rigid-body pair (pair =
        // -1 otherwise); vec: the eigenvector column of its shape
        Eigen::Index root = -1, pair = -1, vec = -1;
    };

    void assemble(const double *theta);
    void state_matrix(Eigen::MatrixXd &A);
    void analyse(bool vectors, std::vector<Mode> &modes, double *growth);
    void complex_vectors();
    bool jacobian();
    void numeric_jacobian();
    void write(const std::vector<Mode> &modes, double *freq_hz, double *zeta, double *shape_re, double *shape_im);

    const vibid_model *model_ = nullptr;
    Eigen::Index n_ = 0, p_ = 0;
    std::vector<double> th_, tp_, tm_;
    Eigen::MatrixXd M_, D_, C_, A_, Ap_, S_;     // S_: M^-1 C or M^-1 D
    Eigen::PartialPivLU<Eigen::MatrixXd> lu_;
    Eigen::EigenSolver<Eigen::MatrixXd> es_;
    Eigen::MatrixXcd V_, W_, I_;                 // right eigenvectors, V^-1, the identity
    Eigen::PartialPivLU<Eigen::MatrixXcd> luV_;
    Eigen::VectorXcd shape_;
    Eigen::MatrixXd J_, JC_, Cv_;                // 2n x p, 2n x p, 2n x 2n
    std::vector<Mode> modes_, modes_p_, modes_m_;
    std::vector<std::pair<double, Eigen::Index>> real_roots_;
};

}  // namespace vibid

#endif
