// stand_ekf.cpp: extended Kalman filter on [y; y'; theta] of a lumped network
// (stand_ekf.hpp), and the identifiability check for partially measured stands.
//
// Per-sample code allocates nothing: every matrix is sized in the constructor and the
// products are written as noalias() lazyProduct into preallocated storage
// (coefficient-based, no GEMM blocking workspace), as in kf_rls.cpp.
#include "stand_ekf.hpp"

#include "api_guard.hpp"
#include "small_linalg.hpp"

#include <vibid/model.h>

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <complex>
#include <cstdio>
#include <cstring>

namespace vibid {

namespace {

using Eigen::Index;
using MatX = Eigen::MatrixXd;
using VecX = Eigen::VectorXd;
using CMat = Eigen::MatrixXcd;
using CVec = Eigen::VectorXcd;

bool measured_disp(const vibid_model &m, std::size_t node) {
    return node == VIBID_BASE ? (m.base_measured & VIBID_MEASURE_DISPLACEMENT) != 0
                              : (m.nodes[node].measured & VIBID_MEASURE_DISPLACEMENT) != 0;
}

// exp(B) for a small matrix with |B|_1 of order 1 or less: scaling by 2^s until
// |B|_1 <= 1/2, Taylor polynomial of degree 12 (truncation below 2e-14 relative), s
// squarings. Allocation-free: T1, T2 are scratch of B's size.
void expm_small(const MatX &B, MatX &out, MatX &T1, MatX &T2) {
    const Index N = B.rows();
    double norm = 0.0;
    for (Index j = 0; j < N; ++j) norm = std::max(norm, B.col(j).cwiseAbs().sum());
    int s = 0;
    while (norm > 0.5 && s < 60) {
        norm *= 0.5;
        ++s;
    }
    const double scale = std::ldexp(1.0, -s);
    // Horner: T = I + B/1 (I + B/2 (I + ... (I + B/12)))
    out.setIdentity();
    for (int k = 12; k >= 1; --k) {
        T1.noalias() = B.lazyProduct(out);
        T1 *= scale / static_cast<double>(k);
        out = T1;
        out.diagonal().array() += 1.0;
    }
    for (int i = 0; i < s; ++i) {
        T2.noalias() = out.lazyProduct(out);
        out = T2;
    }
}

// Noise variance of a sampled signal from its k-th differences: for white noise
// var(diff_k) = C(2k, k) sigma^2, while a smooth signal's k-th difference shrinks as
// (w h)^k. The smallest of k = 2..6 bounds the noise from above and meets it when the
// signal is sampled finely enough (20 samples per period: (w h)^4 = 0.0024).
double difference_noise_var(const double *x, std::size_t stride, std::size_t len) {
    static const double binom[7] = {1, 2, 6, 20, 70, 252, 924};
    double best = HUGE_VAL;
    for (int k = 2; k <= 6; ++k) {
        if (len < static_cast<std::size_t>(k) + 8) break;
        double ss = 0.0;
        std::size_t cnt = 0;
        for (std::size_t t = static_cast<std::size_t>(k); t < len; ++t) {
            // k-th difference by binomial coefficients (-1)^j C(k, j)
            double d = 0.0, c = 1.0;
            for (int j = 0; j <= k; ++j) {
                d += ((j & 1) ? -c : c) * x[(t - static_cast<std::size_t>(j)) * stride];
                c = c * static_cast<double>(k - j) / static_cast<double>(j + 1);
            }
            ss += d * d;
            ++cnt;
        }
        best = std::min(best, ss / static_cast<double>(cnt) / binom[k]);
    }
    return best;
}

// Natural frequencies (rad/s) of the linear part at theta (nullptr = nominal): smallest
// and largest; 0 when not available.
void nominal_omega_range(const vibid_model &m, double &wmin, double &wmax) {
    const Index n = static_cast<Index>(m.nodes.size());
    MatX M(n, n), D(n, n), C(n, n);
    wmin = wmax = 0.0;
    if (vibid_model_assemble(&m, nullptr, M.data(), D.data(), C.data(), nullptr, nullptr, nullptr) != VIBID_OK) return;
    Eigen::GeneralizedSelfAdjointEigenSolver<MatX> es(C, M, Eigen::EigenvaluesOnly);
    if (es.info() != Eigen::Success) return;
    wmin = HUGE_VAL;
    for (Index i = 0; i < n; ++i) {
        const double w = std::sqrt(std::max(es.eigenvalues()(i), 0.0));
        if (w > 0.0) wmin = std::min(wmin, w);
        wmax = std::max(wmax, w);
    }
    if (!(wmin < HUGE_VAL)) wmin = 0.0;
}

}  // namespace

// ---------------------------------------------------------------------------------
// Identifiability from the measured channels (before any sample)

namespace {

// Something unknown, a lumped network, and a start value for every unknown: the
// state-space estimator starts from the stand's nominal values.
void check_start_values(const vibid_model &m) {
    const std::size_t p = m.param_term.size();
    if (p == 0) throw_error(VIBID_E_OUT_OF_RANGE, "nothing unknown: every mass, element and gain is known");
    if (m.full_matrix)
        throw_error(VIBID_E_UNSUPPORTED, "the state-space estimator needs a lumped network (nodes and elements), not "
                                         "full matrices");
    std::string missing;
    for (std::size_t i = 0; i < p; ++i) {
        const Term &t = m.terms[m.param_term[i]];
        if (!(t.value != 0.0) || !std::isfinite(t.value)) missing += (missing.empty() ? "'" : ", '") + t.name + "'";
    }
    if (!missing.empty())
        throw_error(VIBID_E_OUT_OF_RANGE,
                    "the state-space estimator (the stand is not fully measured) starts from the stand's nominal "
                    "values; these unknowns have none: %s (give `value`/`mass`/`gain` as the start value)",
                    missing.c_str());
}

// A base motion the filter can take as an input, some measured node to compare the
// model with, and something that excites the stand.
void check_measured_and_excited(const vibid_model &m) {
    if (m.has_base && !measured_disp(m, VIBID_BASE))
        throw_error(VIBID_E_DIMENSION, "base: its displacement must be measured (it is an input of the stand's "
                                       "model; an unmeasured base motion cannot be told from the stand's response)");
    std::size_t nmeas = 0;
    for (const auto &nd : m.nodes) nmeas += static_cast<std::size_t>(__builtin_popcount(nd.measured));
    if (nmeas == 0) throw_error(VIBID_E_DIMENSION, "no node is measured: nothing to compare the model with");
    if (m.inputs.empty() && !m.has_base && m.disturbances.empty())
        throw_error(VIBID_E_NOT_IDENTIFIABLE, "nothing excites the stand: no measured force input, no base motion "
                                              "and no disturbance (declare the random excitation as a disturbance)");
}

// Something known (a term or a disturbance intensity) fixes the scale of the unknowns.
void check_scale_fixed(const vibid_model &m) {
    bool any_known = false;
    for (const auto &t : m.terms)
        if (!t.unknown && t.value != 0.0) any_known = true;
    for (const auto &w : m.disturbances)
        if (w.std_dev > 0.0) any_known = true;
    if (!any_known)
        throw_error(VIBID_E_NOT_IDENTIFIABLE,
                    "nothing known fixes the scale: with every mass, element, gain and disturbance intensity unknown, "
                    "all of them times any factor fit the data equally well; make one known");
}

// The sensitivity test's frequencies (rad/s): nf log-spaced from lo to hi, spanning the
// nominal modes, below the Nyquist frequency pi / h.
struct FrequencyGrid {
    double lo = 0.0, hi = 0.0;
    int nf = 96;
    double at(int f) const { return lo * std::pow(hi / lo, static_cast<double>(f) / (nf - 1)); }
};

FrequencyGrid frequency_grid(const vibid_model &m, double h) {
    double wmin = 0.0, wmax = 0.0;
    nominal_omega_range(m, wmin, wmax);
    const double wnyq = M_PI / h;
    if (!(wmax > 0.0)) wmin = wmax = 0.1 * wnyq;
    FrequencyGrid g;
    g.lo = std::max(0.2 * wmin, 1e-6 * wnyq);
    g.hi = std::min(5.0 * wmax, 0.95 * wnyq);
    return g;
}

// The unknowns of the test, its columns: the linear parameters (indices into the model's
// unknowns; cubic ones have no linear sensitivity and are named in cubic_names), then the
// disturbances of unknown intensity (indices into m.disturbances).
struct TestedUnknowns {
    std::vector<std::size_t> cols, unknown_w;
    std::string cubic_names;
    std::size_t size() const { return cols.size() + unknown_w.size(); }
    std::string name(const vibid_model &m, std::size_t c) const {
        return c < cols.size() ? m.terms[m.param_term[cols[c]]].name
                               : "intensity of " + m.disturbances[unknown_w[c - cols.size()]].name;
    }
};

TestedUnknowns tested_unknowns(const vibid_model &m) {
    TestedUnknowns u;
    for (std::size_t l = 0; l < m.disturbances.size(); ++l)
        if (m.disturbances[l].std_dev == 0.0) u.unknown_w.push_back(l);
    for (std::size_t i = 0; i < m.param_term.size(); ++i) {
        if (m.terms[m.param_term[i]].kind == VIBID_PARAM_CUBIC)
            u.cubic_names += (u.cubic_names.empty() ? "'" : ", '") + m.terms[m.param_term[i]].name + "'";
        else
            u.cols.push_back(i);
    }
    return u;
}

// The stand's matrices at its nominal values (th) and the structure of each unknown i
// (model.h: Mi[i] ... cbi[i]), n x n and n x r.
struct NominalStand {
    MatX M0, D0, C0, B0;
    VecX db0, cb0;
    std::vector<double> th;
    std::vector<MatX> Mi, Di, Ci, Bi;
    std::vector<VecX> dbi, cbi;
};

NominalStand nominal_stand(const vibid_model &m) {
    const std::size_t p = m.param_term.size(), r = m.inputs.size();
    const Index nn = static_cast<Index>(m.nodes.size());
    NominalStand s;
    s.M0.resize(nn, nn);
    s.D0.resize(nn, nn);
    s.C0.resize(nn, nn);
    s.B0.resize(nn, static_cast<Index>(r));
    s.db0.resize(nn);
    s.cb0.resize(nn);
    s.th.resize(p);
    vibid_model_nominal(&m, s.th.data());
    vibid_model_assemble(&m, s.th.data(), s.M0.data(), s.D0.data(), s.C0.data(), s.B0.data(), s.db0.data(),
                         s.cb0.data());
    s.Mi.assign(p, MatX(nn, nn));
    s.Di.assign(p, MatX(nn, nn));
    s.Ci.assign(p, MatX(nn, nn));
    s.Bi.assign(p, MatX(nn, static_cast<Index>(r)));
    s.dbi.assign(p, VecX(nn));
    s.cbi.assign(p, VecX(nn));
    for (std::size_t i = 0; i < p; ++i)
        vibid_model_structure(&m, i, s.Mi[i].data(), s.Di[i].data(), s.Ci[i].data(), s.Bi[i].data(), s.dbi[i].data(),
                              s.cbi[i].data());
    return s;
}

// A measured quantity: node, and q = 0 displacement, 1 velocity, 2 acceleration.
struct MeasuredOutput {
    std::size_t node;
    int q;
};

std::vector<MeasuredOutput> measured_outputs(const vibid_model &m) {
    std::vector<MeasuredOutput> outs;
    for (std::size_t i = 0; i < m.nodes.size(); ++i)
        for (int q = 0; q < 3; ++q)
            if (m.nodes[i].measured & (1u << q)) outs.push_back({i, q});
    return outs;
}

// The responses at one frequency w: Y (n x (ni + nw)) to the measured inputs (forces,
// then the base, c_b + i w d_b) and to a unit force of each disturbance, and their
// relative sensitivities dY[c] = dY / d log theta to the tested parameters.
struct Responses {
    CMat Y;
    std::vector<CMat> dY;
};

Responses responses_at(const vibid_model &m, const NominalStand &s, const TestedUnknowns &u, double w) {
    const std::size_t r = m.inputs.size(), nw = m.disturbances.size();
    const Index nn = static_cast<Index>(m.nodes.size());
    const Index ni = static_cast<Index>(r) + (m.has_base ? 1 : 0);  // measured inputs (base last)
    const std::complex<double> iw(0.0, w);
    CMat Z = (-w * w) * s.M0.cast<std::complex<double>>() + iw * s.D0.cast<std::complex<double>>() +
             s.C0.cast<std::complex<double>>();
    Eigen::PartialPivLU<CMat> lu(Z);
    // Input matrix: measured forces, base (c_b + i w d_b), disturbances (unit force).
    CMat F(nn, ni + static_cast<Index>(nw));
    F.setZero();
    for (Index j = 0; j < static_cast<Index>(r); ++j) F.col(j) = s.B0.col(j).cast<std::complex<double>>();
    if (m.has_base)
        F.col(static_cast<Index>(r)) = s.cb0.cast<std::complex<double>>() + iw * s.db0.cast<std::complex<double>>();
    for (std::size_t l = 0; l < nw; ++l) F(static_cast<Index>(m.disturbances[l].node), ni + static_cast<Index>(l)) = 1.0;
    Responses out;
    out.Y = lu.solve(F);
    const CMat &Y = out.Y;
    out.dY.resize(u.size());
    for (std::size_t c = 0; c < u.cols.size(); ++c) {
        const std::size_t i = u.cols[c];
        CMat dZ = (-w * w) * s.Mi[i].cast<std::complex<double>>() + iw * s.Di[i].cast<std::complex<double>>() +
                  s.Ci[i].cast<std::complex<double>>();
        CMat dF(nn, ni + static_cast<Index>(nw));
        dF.setZero();
        for (Index j = 0; j < static_cast<Index>(r); ++j) dF.col(j) = s.Bi[i].col(j).cast<std::complex<double>>();
        if (m.has_base)
            dF.col(static_cast<Index>(r)) =
                s.cbi[i].cast<std::complex<double>>() + iw * s.dbi[i].cast<std::complex<double>>();
        // relative sensitivity: d/d log theta
        out.dY[c] = lu.solve(dF - dZ * Y) * s.th[i];
    }
    return out;
}

// The factor of a measured quantity q at w: 1, i w, -w^2.
std::complex<double> output_factor(int q, double w) {
    return q == 0 ? std::complex<double>(1.0) : q == 1 ? std::complex<double>(0.0, w) : std::complex<double>(-w * w);
}

// Rows (real and imaginary parts, length u.size()) of the measured inputs' transfer
// functions' sensitivities, relative to their size, at w.
void append_transfer_rows(const vibid_model &m, const TestedUnknowns &u, const std::vector<MeasuredOutput> &outs,
                          const Responses &resp, double w, std::vector<VecX> &rows) {
    const Index ni = static_cast<Index>(m.inputs.size()) + (m.has_base ? 1 : 0);
    const Index nq = static_cast<Index>(u.size());
    for (const MeasuredOutput &out : outs) {
        const std::complex<double> g = output_factor(out.q, w);
        const Index node = static_cast<Index>(out.node);
        for (Index j = 0; j < ni; ++j) {
            const double mag = std::abs(g * resp.Y(node, j));
            if (!(mag > 1e-300)) continue;
            VecX re = VecX::Zero(nq), im = VecX::Zero(nq);
            for (std::size_t c = 0; c < u.cols.size(); ++c) {
                const std::complex<double> v = g * resp.dY[c](node, j) / mag;
                re(static_cast<Index>(c)) = v.real();
                im(static_cast<Index>(c)) = v.imag();
            }
            rows.push_back(re);
            rows.push_back(im);
        }
    }
}

// Rows of the disturbances' output (cross-)spectra S_oo' = sum_l R_l T_ol conj(T_o'l), the
// only thing observable of them, relative to their size, at w: their sensitivities to the
// tested parameters and to the unknown intensities R_l.
void append_spectrum_rows(const vibid_model &m, const TestedUnknowns &u, const std::vector<MeasuredOutput> &outs,
                          const Responses &resp, double w, std::vector<VecX> &rows) {
    const std::size_t nw = m.disturbances.size();
    const Index ni = static_cast<Index>(m.inputs.size()) + (m.has_base ? 1 : 0);
    const Index nq = static_cast<Index>(u.size());
    const CMat &Y = resp.Y;
    for (std::size_t o = 0; o < outs.size(); ++o)
        for (std::size_t o2 = o; o2 < outs.size(); ++o2) {
            const Index a = static_cast<Index>(outs[o].node), b = static_cast<Index>(outs[o2].node);
            const std::complex<double> ga = output_factor(outs[o].q, w), gb = output_factor(outs[o2].q, w);
            std::complex<double> S(0.0);
            std::vector<double> Rl(nw);
            for (std::size_t l = 0; l < nw; ++l) {
                Rl[l] = m.disturbances[l].std_dev > 0.0 ? m.disturbances[l].std_dev * m.disturbances[l].std_dev : 1.0;
                S += Rl[l] * ga * Y(a, ni + static_cast<Index>(l)) * std::conj(gb * Y(b, ni + static_cast<Index>(l)));
            }
            const double mag = std::abs(S);
            if (!(mag > 1e-300)) continue;
            VecX re = VecX::Zero(nq), im = VecX::Zero(nq);
            for (std::size_t c = 0; c < u.cols.size(); ++c) {
                std::complex<double> d(0.0);
                for (std::size_t l = 0; l < nw; ++l) {
                    const Index cl = ni + static_cast<Index>(l);
                    d += Rl[l] * (ga * resp.dY[c](a, cl) * std::conj(gb * Y(b, cl)) +
                                  ga * Y(a, cl) * std::conj(gb * resp.dY[c](b, cl)));
                }
                re(static_cast<Index>(c)) = (d / mag).real();
                im(static_cast<Index>(c)) = (d / mag).imag();
            }
            for (std::size_t k = 0; k < u.unknown_w.size(); ++k) {
                const std::size_t l = u.unknown_w[k];
                const Index cl = ni + static_cast<Index>(l);
                const std::complex<double> d = Rl[l] * ga * Y(a, cl) * std::conj(gb * Y(b, cl));
                re(static_cast<Index>(u.cols.size() + k)) = (d / mag).real();
                im(static_cast<Index>(u.cols.size() + k)) = (d / mag).imag();
            }
            rows.push_back(re);
            if (o2 != o) rows.push_back(im);
        }
}

// The relative sensitivities of everything measured to the tested unknowns over the
// grid: one row per real number observed, u.size() columns.
MatX sensitivity_matrix(const vibid_model &m, const FrequencyGrid &grid, const TestedUnknowns &u) {
    const NominalStand stand = nominal_stand(m);
    const std::vector<MeasuredOutput> outs = measured_outputs(m);
    std::vector<VecX> rows;  // each a real row of length u.size()
    for (int f = 0; f < grid.nf; ++f) {
        const double w = grid.at(f);
        const Responses resp = responses_at(m, stand, u, w);
        append_transfer_rows(m, u, outs, resp, w, rows);
        if (!m.disturbances.empty()) append_spectrum_rows(m, u, outs, resp, w, rows);
    }
    MatX J(static_cast<Index>(rows.size()), static_cast<Index>(u.size()));
    for (std::size_t k = 0; k < rows.size(); ++k) J.row(static_cast<Index>(k)) = rows[k].transpose();
    return J;
}

// The rank test on the sensitivities J: throws naming the unknowns in the directions the
// measured responses do not determine, else returns the report line.
std::string rank_test(const vibid_model &m, const FrequencyGrid &grid, const TestedUnknowns &u, const MatX &J) {
    const std::size_t nq = u.size();
    Eigen::JacobiSVD<MatX> svd(J, Eigen::ComputeFullV);
    const VecX sv = svd.singularValues();
    // Structural non-identifiability gives singular values at rounding level (1e-15 of
    // the largest); a poorly excited but identifiable direction stays far above 1e-9.
    const double tol = 1e-9 * (sv.size() ? sv(0) : 0.0);
    Index rank = 0;
    for (Index k = 0; k < sv.size(); ++k)
        if (sv(k) > tol) ++rank;
    if (rank < static_cast<Index>(nq)) {
        VecX weight = VecX::Zero(static_cast<Index>(nq));
        for (Index k = rank; k < static_cast<Index>(nq); ++k) weight += svd.matrixV().col(k).cwiseAbs2();
        std::string bad;
        for (Index c = 0; c < static_cast<Index>(nq); ++c)
            if (weight(c) > 1e-3) bad += (bad.empty() ? "'" : ", '") + u.name(m, static_cast<std::size_t>(c)) + "'";
        throw_error(VIBID_E_NOT_IDENTIFIABLE,
                    "not identifiable from the measured channels: %s (at the nominal values the measured responses "
                    "determine only %ld of these %zu unknowns; sensitivity rank test over %.3g..%.3g Hz); make them "
                    "known or measure more of the stand",
                    bad.c_str(), static_cast<long>(rank), nq, grid.lo / (2 * M_PI), grid.hi / (2 * M_PI));
    }
    char buf[320];
    std::snprintf(buf, sizeof buf,
                  "identifiability: the measured channels determine all %zu unknowns at the nominal values "
                  "(sensitivity rank %zu over %.3g..%.3g Hz, smallest relative singular value %.2g)%s",
                  nq, nq, grid.lo / (2 * M_PI), grid.hi / (2 * M_PI), sv(sv.size() - 1) / sv(0),
                  u.cubic_names.empty() ? "" : "; cubic coefficients are not part of the test");
    return buf;
}

}  // namespace

void check_identifiable_state_space(const vibid_model &m, double h, std::string &report) {
    check_start_values(m);
    check_measured_and_excited(m);
    check_scale_fixed(m);
    const FrequencyGrid grid = frequency_grid(m, h);
    const TestedUnknowns u = tested_unknowns(m);
    if (u.size() == 0) {
        report = "identifiability: only cubic coefficients are unknown; they are determined by the amplitude of the "
                 "response, not checked before the data";
        return;
    }
    report = rank_test(m, grid, u, sensitivity_matrix(m, grid, u));
}

// ---------------------------------------------------------------------------------
// The filter

StandEkf::StandEkf(const vibid_model &m, const StandEkfSettings &s) : model_(&m), set_(s) {
    n_ = static_cast<Index>(m.nodes.size());
    p_ = static_cast<Index>(m.param_term.size());
    r_ = static_cast<Index>(m.inputs.size());
    base_smooth_ = m.base_hold != VIBID_HOLD_ZOH;
    nb_ = m.has_base ? 1 : 0;
    nw_ = static_cast<Index>(m.disturbances.size());
    nc_ = m.nonlinear ? 1 : 0;
    ne_ = r_ + nb_ + nw_ + nc_;
    nx_ = 2 * n_;
    N_ = nx_ + 2 * ne_;
    na_ = nx_ + p_;
    nf_ = set_.kf_rls ? nx_ : na_;
    nch_ = static_cast<Index>(m.channels.size());
    if (nb_) {
        col_s_ = nx_ + r_;
        if (base_smooth_) col_sd_ = nx_ + ne_ + r_;  // its slope: the base velocity over the interval
    }
    held_base_kick_ = m.has_base && !base_smooth_ && m.base_damper;
    for (const auto &u : m.inputs) input_smooth_.push_back(u.hold != VIBID_HOLD_ZOH);
    input_ch_.assign(m.input_channel.begin(), m.input_channel.end());
    base_disp_ch_ = m.base_channel[0];
    base_vel_ch_ = m.base_channel[1];
    for (std::size_t i = 0; i < m.nodes.size(); ++i)
        for (int q = 0; q < 3; ++q)
            if (m.node_channel[i][static_cast<std::size_t>(q)] != kNoChannel)
                meas_.push_back(Meas{m.node_channel[i][static_cast<std::size_t>(q)], i, q,
                                     m.node_noise[i][static_cast<std::size_t>(q)]});
    base_declared_std_ = m.base_noise[0];
    nz_ = static_cast<Index>(meas_.size());
    for (const auto &e : m.elements)
        if (e.kind == VIBID_ELEMENT_CUBIC_SPRING) {
            long param = -1;
            for (const auto &t : m.terms)
                if (t.name == e.name) param = t.param;
            cubics_.push_back(Cubic{e.a, e.b, param, e.value});
        }
    cubic_lin_.assign(cubics_.size(), {0.0, 0.0});
    for (const auto &w : m.disturbances) {
        dist_declared_.push_back(w.std_dev);
        dist_node_.push_back(w.node);
    }


    // Structure matrices: the known part (theta = 0) and each unknown's derivative.
    const Index n = n_, r = r_;
    MatX Mm(n, n);
    auto fetch = [&](long i, VecX &Md, MatX &Dm, MatX &Cm, MatX &Bm, VecX &dbv, VecX &cbv) {
        Dm.resize(n, n);
        Cm.resize(n, n);
        Bm.resize(n, r);
        dbv.resize(n);
        cbv.resize(n);
        vibid_status st;
        if (i < 0) {
            std::vector<double> zero(static_cast<std::size_t>(p_), 0.0);
            st = vibid_model_assemble(&m, zero.data(), Mm.data(), Dm.data(), Cm.data(), Bm.data(), dbv.data(),
                                      cbv.data());
        } else {
            st = vibid_model_structure(&m, static_cast<std::size_t>(i), Mm.data(), Dm.data(), Cm.data(), Bm.data(),
                                       dbv.data(), cbv.data());
        }
        if (st != VIBID_OK) throw_error(st, "%s", vibid_last_error());
        Md = Mm.diagonal();
    };
    fetch(-1, M0_, D0_, C0_, B0_, db0_, cb0_);
    Mi_.resize(static_cast<std::size_t>(p_));
    Di_.resize(static_cast<std::size_t>(p_));
    Ci_.resize(static_cast<std::size_t>(p_));
    Bi_.resize(static_cast<std::size_t>(p_));
    dbi_.resize(static_cast<std::size_t>(p_));
    cbi_.resize(static_cast<std::size_t>(p_));
    for (Index i = 0; i < p_; ++i) {
        const std::size_t k = static_cast<std::size_t>(i);
        fetch(i, Mi_[k], Di_[k], Ci_[k], Bi_[k], dbi_[k], cbi_[k]);
    }
    theta_start_.resize(p_);
    vibid_model_nominal(&m, theta_start_.data());
    prov_theta_.setZero(p_);
    prov_cov_.setZero(p_, p_);

    Mv_.resize(n);
    Minv_.resize(n);
    cb_.resize(n);
    db_.resize(n);
    cbt_.resize(n);
    gconst_.resize(n);
    D_.resize(n, n);
    C_.resize(n, n);
    Ct_.resize(n, n);
    B_.resize(n, r);
    for (MatX *X : {&A_, &E4_, &E2_, &E1_, &T1_, &T2_, &Pow_}) X->setZero(N_, N_);
    dArows_.assign(static_cast<std::size_t>(p_), MatX::Zero(n, N_));
    for (auto &x : xi_) x.setZero(N_);
    acc_.setZero(N_);
    gv_.setZero(n);
    a_.setZero(na_);
    scale_.setOnes(na_);
    P_.setZero(na_, na_);
    for (MatX *X : {&F_, &FP_, &IKH_}) X->setZero(na_, na_);
    Hm_.setZero(nz_, na_);
    PHt_.setZero(na_, nz_);
    K_.setZero(na_, nz_);
    Sz_.setZero(nz_, nz_);
    Rz_.setZero(nz_, nz_);
    zhat_.setZero(nz_);
    nu_.setZero(nz_);
    nu_sd_.setZero(nz_);
    Rv_.setZero(nz_);
    Rw_.setZero(nw_);
    window_.assign(set_.window * static_cast<std::size_t>(nch_), 0.0);
    prev_.assign(static_cast<std::size_t>(nch_), 0.0);
    prev2_.assign(static_cast<std::size_t>(nch_), 0.0);
    double wmin = 0.0, wmax = 0.0;
    nominal_omega_range(m, wmin, wmax);
    omega_ref_ = wmax > 0.0 ? wmax : 0.1 * M_PI / set_.h;
    bool unsensed = false;
    for (const auto &nd : m.nodes) unsensed = unsensed || nd.measured == 0;
    // Two periods of the slowest nominal mode (samples), within [50, window / 2]: the
    // settling time of unmeasured states and the time constant of the tempering.
    const double period = wmin > 0.0 ? 2.0 * M_PI / wmin / set_.h : 50.0;
    const double settle = std::max(50.0, std::min(2.0 * period, 0.5 * static_cast<double>(set_.window)));
    temper_tau_ = settle;
    if (unsensed) settle_steps_ = static_cast<unsigned long long>(settle);
    if (set_.kf_rls) {
        for (Index i = 0; i < n_; ++i)
            if (m.nodes[static_cast<std::size_t>(i)].measured) rows_.push_back(i);
        // An unknown that enters no measured node's equation has no row to learn from.
        std::string unseen;
        for (Index k = 0; k < p_; ++k) {
            const std::size_t kk = static_cast<std::size_t>(k);
            bool seen = false;
            for (Index i : rows_) {
                seen = seen || Mi_[kk](i) != 0.0 || Di_[kk].row(i).any() || Ci_[kk].row(i).any() ||
                       (r_ && Bi_[kk].row(i).any()) || dbi_[kk](i) != 0.0 || cbi_[kk](i) != 0.0;
                for (const auto &c : cubics_)
                    seen = seen || (c.param == k && (static_cast<Index>(c.a) == i || static_cast<Index>(c.b) == i));
            }
            if (!seen) unseen += (unseen.empty() ? "'" : ", '") + m.terms[m.param_term[kk]].name + "'";
        }
        if (!unseen.empty())
            throw_error(VIBID_E_NOT_IDENTIFIABLE,
                        "KF+RLS cannot estimate %s: they act only on nodes without a sensor, whose equations give the "
                        "regression nothing but the filter's own prediction (use method ekf)",
                        unseen.c_str());
        const Index nr = static_cast<Index>(rows_.size());
        vibid_rls_config rc;
        vibid_rls_config_init(&rc, static_cast<std::size_t>(p_), 1);
        rc.n_equations = static_cast<std::size_t>(nr);
        rc.forgetting = set_.forgetting;
        // Never less certain than the prior (forgetting without excitation winds up).
        rc.windup = VIBID_RLS_WINDUP_TRACE_BOUND;
        rc.trace_max = static_cast<double>(p_) * set_.prior_rel * set_.prior_rel;
        rls_.reset(vibid_rls_create(&rc));
        if (!rls_) throw_error(VIBID_E_NO_MEMORY, "KF+RLS: %s", vibid_last_error());
        phi_.setZero(p_, nr);
        rls_P0_ = MatX::Identity(p_, p_) * (set_.prior_rel * set_.prior_rel);
        target_.setZero(nr);
        eq_.setZero(nr);
        row_scale_.setOnes(nr);
        rls_theta_.setOnes(p_);
        dv_.setZero(n_);
        dy_.setZero(n_);
        iy_.setZero(n_);
        iu_.setZero(r_);
    }
    x_prev_.setZero(nx_);
    cov_.setZero(p_, p_);
    sc_U_.setZero(p_, kScoreBlocks);
    sc_W_.setZero(p_, kScoreBlocks);
    sc_J_.assign(static_cast<std::size_t>(kScoreBlocks), MatX::Zero(p_, p_));
    for (MatX *X : {&sc_L_, &sc_G_, &sc_T_}) X->setZero(p_, p_);
    sc_psi_.setZero(p_, nz_);
    sc_Spsi_.setZero(nz_, p_);
    for (VecX *x : {&sc_u_, &sc_th_, &sc_w_}) x->setZero(p_);
    for (int j = 0; j < 2; ++j) {
        drift_theta_[j].setZero(p_);
        drift_var_[j].setZero(p_);
    }
}

void StandEkf::reset() {
    n_window_ = 0;
    have_prev_ = have_prev2_ = false;
    stats_ = StandEkfStats{};
    prov_stats_ = StandEkfStats{};
    prov_at_ = 0;
}

void StandEkf::set_start(const double *theta0) {
    for (Index i = 0; i < p_; ++i) theta_start_(i) = theta0[i];
}

// X(theta) = X0 + sum theta_i X_i at the parameters in a_.
void StandEkf::assemble() {
    Mv_ = M0_;
    D_ = D0_;
    C_ = C0_;
    B_ = B0_;
    cb_ = cb0_;
    db_ = db0_;
    for (Index i = 0; i < p_; ++i) {
        const double t = a_(nx_ + i);
        const std::size_t k = static_cast<std::size_t>(i);
        Mv_.noalias() += t * Mi_[k];
        D_.noalias() += t * Di_[k];
        C_.noalias() += t * Ci_[k];
        if (r_) B_.noalias() += t * Bi_[k];
        cb_.noalias() += t * cbi_[k];
        db_.noalias() += t * dbi_[k];
    }
    Minv_ = Mv_.cwiseInverse();
}

// Relative displacement of cubic spring e: y_a - y_b (y_ground = 0, y_base = s).
double StandEkf::cubic_rho(std::size_t e, const double *y, double s) const {
    const Cubic &c = cubics_[e];
    const double yb = c.b == VIBID_GROUND ? 0.0 : c.b == VIBID_BASE ? s : y[c.b];
    return y[c.a] - yb;
}

// Cubic springs over [t_k, t_{k+1}], about the interval's midpoint: with rho(t) ~ rho_m +
// rho' (t - t_m), eps rho^3 = eps (rho_m^3 + 3 rho_m^2 d + 3 rho_m d^2 + d^3), d = rho - rho_m;
// the linear part is a spring 3 eps rho_m^2 (into Ct_, cbt_), the rest a constant force
// (gconst_, right-hand side): 2 eps rho_m^3 from the linearisation less the interval mean of
// 3 eps rho_m d^2, eps rho_m rho'^2 h^2 / 4 (d^3 averages to zero). About t_k instead, the
// neglected quadratic term averaged four times as much and biased the cubic coefficient
// (+0.42 % against a standard error of 0.085 % on a 2-DOF stand at 2 kHz, ident.ekf).
// y, v: the state at t_k; s, sd: base displacement and velocity there.
void StandEkf::linearise_cubics(const double *y, const double *v, double s, double sd) {
    Ct_ = C_;
    cbt_ = cb_;
    gconst_.setZero();
    const double h = set_.h;
    for (std::size_t e = 0; e < cubics_.size(); ++e) {
        const Cubic &c = cubics_[e];
        const double eps = c.param >= 0 ? a_(nx_ + c.param) : c.value;
        const double rate = v[c.a] - (c.b == VIBID_GROUND ? 0.0 : c.b == VIBID_BASE ? sd : v[c.b]);
        const double rho = cubic_rho(e, y, s) + 0.5 * h * rate;
        cubic_lin_[e] = {3.0 * rho * rho, 2.0 * rho * rho * rho - 0.25 * rho * rate * rate * h * h};
        const double k = eps * cubic_lin_[e].first, g = eps * cubic_lin_[e].second;
        const Index ia = static_cast<Index>(c.a);
        Ct_(ia, ia) += k;
        gconst_(ia) += g;
        if (c.b == VIBID_BASE) {
            cbt_(ia) += k;
        } else if (c.b != VIBID_GROUND) {
            const Index ib = static_cast<Index>(c.b);
            Ct_(ia, ib) -= k;
            Ct_(ib, ia) -= k;
            Ct_(ib, ib) += k;
            gconst_(ib) -= g;
        }
    }
}

// A~ (velocity rows; the others are constant) and its derivatives d A~ / d theta_i.
// Columns: [y | v | e = (u, s, w, 1) | e' (slopes)].
void StandEkf::build_transition() {
    const Index n = n_, eu = nx_, ew = eu + r_ + nb_, e1 = ew + nw_, es = col_s_, ds = col_sd_;
    A_.setZero();
    for (Index i = 0; i < n; ++i) A_(i, n + i) = 1.0;
    for (Index j = 0; j < ne_; ++j) A_(nx_ + j, nx_ + ne_ + j) = 1.0;
    for (Index i = 0; i < n; ++i) {
        const double mi = Minv_(i);
        for (Index j = 0; j < n; ++j) {
            A_(n + i, j) = -mi * Ct_(i, j);
            A_(n + i, n + j) = -mi * D_(i, j);
        }
        for (Index j = 0; j < r_; ++j) A_(n + i, eu + j) = mi * B_(i, j);
        if (es >= 0) A_(n + i, es) = mi * cbt_(i);
        if (ds >= 0) A_(n + i, ds) = mi * db_(i);
        if (nc_) A_(n + i, e1) = mi * gconst_(i);
    }
    for (Index l = 0; l < nw_; ++l) {
        const Index node = static_cast<Index>(dist_node_[static_cast<std::size_t>(l)]);
        A_(n + node, ew + l) = Minv_(node);
    }
    if (set_.kf_rls) return;  // the KF+RLS needs no parameter Jacobian
    // d(M^-1 X)/d theta_i = M^-1 (X_i - M_i M^-1 X), M diagonal.
    for (Index k = 0; k < p_; ++k) {
        const std::size_t kk = static_cast<std::size_t>(k);
        MatX &dA = dArows_[kk];
        dA.setZero();
        const VecX &Mk = Mi_[kk];
        for (Index i = 0; i < n; ++i) {
            const double mi = Minv_(i), dmi = -mi * mi * Mk(i);  // d(1/m_i)
            for (Index j = 0; j < n; ++j) {
                dA(i, j) = -(dmi * Ct_(i, j) + mi * Ci_[kk](i, j));
                dA(i, n + j) = -(dmi * D_(i, j) + mi * Di_[kk](i, j));
            }
            for (Index j = 0; j < r_; ++j) dA(i, eu + j) = dmi * B_(i, j) + mi * Bi_[kk](i, j);
            if (es >= 0) dA(i, es) = dmi * cbt_(i) + mi * cbi_[kk](i);
            if (ds >= 0) dA(i, ds) = dmi * db_(i) + mi * dbi_[kk](i);
            if (nc_) dA(i, e1) = dmi * gconst_(i);
        }
        for (Index l = 0; l < nw_; ++l) {
            const Index nd = static_cast<Index>(dist_node_[static_cast<std::size_t>(l)]);
            dA(nd, ew + l) = -Minv_(nd) * Minv_(nd) * Mk(nd);
        }
    }
    // Cubic coefficients: their linearisation's derivative (3 rho0^2 spring, 2 rho0^3 force).
    for (std::size_t e = 0; e < cubics_.size(); ++e) {
        const Cubic &c = cubics_[e];
        if (c.param < 0) continue;
        MatX &dA = dArows_[static_cast<std::size_t>(c.param)];
        const double k = cubic_lin_[e].first, g = cubic_lin_[e].second;  // linearise_cubics()
        const Index ia = static_cast<Index>(c.a);
        dA(ia, ia) -= Minv_(ia) * k;
        dA(ia, e1) += Minv_(ia) * g;
        if (c.b == VIBID_BASE) {
            dA(ia, es) += Minv_(ia) * k;
        } else if (c.b != VIBID_GROUND) {
            const Index ib = static_cast<Index>(c.b);
            dA(ia, ib) += Minv_(ia) * k;
            dA(ib, ia) += Minv_(ib) * k;
            dA(ib, ib) -= Minv_(ib) * k;
            dA(ib, e1) -= Minv_(ib) * g;
        }
    }
}

double StandEkf::base_disp(const double *ch) const { return base_disp_ch_ >= 0 ? ch[base_disp_ch_] : 0.0; }

// Base displacement and velocity at the instant of `ch` (prev: the sample before, or
// nullptr): the sample and, for a smooth base, its measured velocity or else the slope of
// the interval ending there; 0 for a held base (constant between its jumps).
void StandEkf::base_now(const double *ch, const double *prev, double &s, double &sd) const {
    s = base_disp(ch);
    sd = 0.0;
    if (!nb_ || !base_smooth_) return;
    if (base_vel_ch_ >= 0)
        sd = ch[base_vel_ch_];
    else if (prev)
        sd = (s - base_disp(prev)) / set_.h;
}

// Fresh state (after a start or a gap): zero with the prior variance (3 typical
// amplitudes); the parameters and their covariance carry on, cross terms dropped.
void StandEkf::init_state() {
    const Index nx = nx_;
    for (Index i = 0; i < nx; ++i) a_(i) = 0.0;
    P_.topRows(nx).setZero();
    P_.leftCols(nx).setZero();
    for (Index i = 0; i < nx; ++i) P_(i, i) = 9.0;
}

void StandEkf::restart_parameters() {
    const Index nx = nx_;
    P_.setZero();
    for (Index i = 0; i < p_; ++i) {
        a_(nx + i) = theta_start_(i);
        scale_(nx + i) = std::fabs(theta_start_(i)) > 0.0 ? std::fabs(theta_start_(i)) : 1.0;
        P_(nx + i, nx + i) = settle_steps_ || set_.kf_rls ? 0.0 : set_.prior_rel * set_.prior_rel;
    }
    if (set_.kf_rls) {
        rls_theta_.setOnes();
        (void)vibid_rls_set_prior(rls_.get(), rls_theta_.data(), rls_P0_.data());
        (void)vibid_rls_set_adaptation(rls_.get(), settle_steps_ ? 0 : 1);
    }
    release_at_ = settle_steps_ ? stats_.n_steps + settle_steps_ : 0;
    nis_check_from_ = stats_.n_steps;
    init_state();
    stats_.nis_avg = 1.0;
    boosts_in_row_ = 0;
    have_prev_ = have_prev2_ = false;
    drift_at_[0] = drift_at_[1] = 0;
    score_reset();
}

// Noise levels and scales from the start window, then the filter runs over it.
void StandEkf::start_from_window() {
    const std::size_t len = n_window_, nch = static_cast<std::size_t>(nch_);
    if (set_.kf_rls) row_scale_.setOnes();
    // Typical displacement amplitude: measured displacements, else velocities / w,
    // accelerations / w^2 (w the highest nominal natural frequency).
    double sy = 0.0;
    for (std::size_t k = 0; k < meas_.size(); ++k) {
        const Meas &mm = meas_[k];
        double mean = 0.0, ss = 0.0;
        for (std::size_t t = 0; t < len; ++t) mean += window_[t * nch + static_cast<std::size_t>(mm.channel)];
        mean /= static_cast<double>(len);
        for (std::size_t t = 0; t < len; ++t) {
            const double d = window_[t * nch + static_cast<std::size_t>(mm.channel)] - mean;
            ss += d * d;
        }
        const double sd = std::sqrt(ss / static_cast<double>(len)) / std::pow(omega_ref_, mm.q);
        sy = std::max(sy, sd);
        // Measurement noise: declared, else from the differences (with a floor of 1e-6 of
        // the signal's spread, so that a noise-free channel does not make the update
        // singular).
        double var = mm.declared_std >= 0.0 ? mm.declared_std * mm.declared_std
                                            : difference_noise_var(window_.data() + mm.channel, nch, len);
        const double floor = 1e-12 * (ss / static_cast<double>(len)) + 1e-300;
        var = std::max(var, floor);
        Rv_(static_cast<Index>(k)) = var;
    }
    sigma_y_ = sy > 0.0 ? sy : 1.0;
    for (Index i = 0; i < n_; ++i) {
        scale_(i) = sigma_y_;
        scale_(n_ + i) = sigma_y_ * omega_ref_;
    }
    // Noise on the base channel: the filter takes the base as an exact input, so its noise
    // reaches the states through c_b s and d_b s' (the slope, where it is amplified by
    // 1/h): entered as process noise (step()).
    if (nb_) {
        const std::size_t ch = static_cast<std::size_t>(base_disp_ch_);
        base_noise_var_ = base_declared_std_ >= 0.0 ? base_declared_std_ * base_declared_std_
                                                    : difference_noise_var(window_.data() + ch, nch, len);
    }
    for (Index l = 0; l < nw_; ++l) {
        const double s = dist_declared_[static_cast<std::size_t>(l)];
        Rw_(l) = s * s;
    }
    // Unknown disturbance intensities: the value that best explains the window (largest
    // innovation likelihood), by golden-section search over log10 R_w, one at a time.
    for (Index l = 0; l < nw_; ++l) {
        if (dist_declared_[static_cast<std::size_t>(l)] > 0.0) continue;
        // Centre of the search: the force that moves the node by the typical amplitude at
        // the highest mode.
        const Index nd = static_cast<Index>(dist_node_[static_cast<std::size_t>(l)]);
        double mass = M0_(nd);
        for (Index i = 0; i < p_; ++i) mass += theta_start_(i) * Mi_[static_cast<std::size_t>(i)](nd);
        const double centre = std::log10(std::pow(mass * omega_ref_ * omega_ref_ * sigma_y_, 2.0));
        double lo = centre - 6.0, hi = centre + 6.0;
        const double gr = 0.5 * (std::sqrt(5.0) - 1.0);
        double x1 = hi - gr * (hi - lo), x2 = lo + gr * (hi - lo);
        Rw_(l) = std::pow(10.0, x1);
        double f1 = window_misfit();
        Rw_(l) = std::pow(10.0, x2);
        double f2 = window_misfit();
        for (int it = 0; it < 40 && hi - lo > 0.01; ++it) {
            if (f1 < f2) {
                hi = x2;
                x2 = x1;
                f2 = f1;
                x1 = hi - gr * (hi - lo);
                Rw_(l) = std::pow(10.0, x1);
                f1 = window_misfit();
            } else {
                lo = x1;
                x1 = x2;
                f1 = f2;
                x2 = lo + gr * (hi - lo);
                Rw_(l) = std::pow(10.0, x2);
                f2 = window_misfit();
            }
        }
        Rw_(l) = std::pow(10.0, 0.5 * (lo + hi));
    }
    if (set_.kf_rls) {
        // Equation-error level of each node's row at the start values: the rows' weights.
        restart_parameters();
        scale_pass_ = true;
        eq_.setZero();
        n_eq_ = 0;
        for (std::size_t t = 0; t < len; ++t)
            if (advance(window_.data() + t * nch) != VIBID_OK) break;
        scale_pass_ = false;
        const double top = n_eq_ ? std::sqrt(eq_.maxCoeff() / static_cast<double>(n_eq_)) : 0.0;
        for (Index q = 0; q < row_scale_.size(); ++q) {
            const double lvl = n_eq_ ? std::sqrt(eq_(q) / static_cast<double>(n_eq_)) : 0.0;
            row_scale_(q) = top > 0.0 ? std::max(lvl, 1e-6 * top) : 1.0;
        }
    }
    restart_parameters();
    stats_.started = true;
    for (std::size_t t = 0; t < len; ++t) (void)push(window_.data() + t * nch);
}

// Innovation misfit (minus twice the log-likelihood, constants dropped) of the filter
// run over the start window from the start values, for the current R_w.
double StandEkf::window_misfit() {
    restart_parameters();
    double total = 0.0;
    const std::size_t nch = static_cast<std::size_t>(nch_);
    for (std::size_t t = 0; t < n_window_; ++t) {
        if (advance(window_.data() + t * nch) != VIBID_OK) return HUGE_VAL;
        // log det S + nu' S^-1 nu from the factor left in Sz_ and the NIS
        double logdet = 0.0;
        for (Index i = 0; i < nz_; ++i) logdet += 2.0 * std::log(Sz_(i, i));
        total += logdet + last_nis_;
    }
    return total;
}

// One sample through the filter: a fresh state (after a start or a gap) is updated with
// it, otherwise the prediction from the previous sample comes first. On success the
// sample becomes the previous one. The model is assembled once, for both halves.
vibid_status StandEkf::advance(const double *cur) {
    assemble();
    vibid_status st;
    if (!have_prev_) {
        init_state();
        st = update(cur);
    } else {
        st = step(prev_.data(), cur);
        if (st == VIBID_OK && set_.kf_rls) regression_step(prev_.data(), cur);
    }
    if (st != VIBID_OK) return st;
    std::copy(prev_.begin(), prev_.end(), prev2_.begin());
    have_prev2_ = have_prev_;
    std::copy(cur, cur + nch_, prev_.begin());
    have_prev_ = true;
    return VIBID_OK;
}

vibid_status StandEkf::push(const double *ch) {
    const std::size_t nch = static_cast<std::size_t>(nch_);
    innovations_fresh_ = false;
    for (std::size_t c = 0; c < nch; ++c)
        if (!std::isfinite(ch[c])) {
            // A gap: the elapsed time and the inputs in it are unknown, so the state
            // restarts at the next sample; the parameters carry on.
            ++stats_.gaps;
            have_prev_ = have_prev2_ = false;
            return VIBID_FAIL(VIBID_E_NONFINITE, "channel %zu is not finite (sample skipped, state restarts)", c);
        }
    if (!stats_.started) {
        std::copy(ch, ch + nch, window_.begin() + static_cast<std::ptrdiff_t>(n_window_ * nch));
        if (++n_window_ == set_.window) {
            start_from_window();
            innovations_fresh_ = false;  // the window's updates are not this sample's alone
        }
        return VIBID_OK;
    }
    const vibid_status st = advance(ch);
    if (st == VIBID_E_DIVERGED) {
        ++stats_.restarts;
        restart_parameters();
        return st;
    }
    if (st != VIBID_OK) return st;
    ++stats_.n_steps;
    innovations_fresh_ = true;
    // Stands with a node that carries no sensor: the parameters are held at their start
    // values while the states of the unmeasured nodes settle (two periods of the slowest
    // mode); released at once, the coupled errors of both made the filter diverge on a
    // 3-DOF chain measured at its end even from the true values.
    if (release_at_ && stats_.n_steps >= release_at_) {
        if (set_.kf_rls)
            (void)vibid_rls_set_adaptation(rls_.get(), 1);
        else
            for (Index i = 0; i < p_; ++i) P_(nx_ + i, nx_ + i) = set_.prior_rel * set_.prior_rel;
        release_at_ = 0;
        nis_check_from_ = stats_.n_steps;
        stats_.nis_avg = 1.0;
        drift_at_[0] = drift_at_[1] = 0;
        score_reset();  // held parameters have no scores; the sums start with their release
    }
    drift_snapshot();
    return VIBID_OK;
}

std::size_t StandEkf::innovations(std::size_t cap, std::size_t *channel, double *nu, double *sd,
                                  double *inflation) const {
    if (!innovations_fresh_) return 0;
    const std::size_t nz = static_cast<std::size_t>(nz_);
    for (std::size_t k = 0; k < std::min(cap, nz); ++k) {
        const Index i = static_cast<Index>(k);
        if (channel) channel[k] = static_cast<std::size_t>(meas_[k].channel);
        if (nu) nu[k] = nu_(i);
        if (sd) sd[k] = nu_sd_(i);
    }
    if (inflation) *inflation = nu_inflation_;
    return nz;
}

// Drift check snapshots: the first once the tempering is through (ten of its time
// constants: x 1e4 has decayed to 1), then each time the steps since the start have
// doubled, the older one kept as the reference. Only for the EKF without forgetting:
// with forgetting the variance does not shrink steadily and change is expected; the
// KF+RLS's error bars are flagged anyway.
void StandEkf::drift_snapshot() {
    if (set_.kf_rls || set_.forgetting < 1.0 || release_at_) return;
    const unsigned long long s = stats_.n_steps - nis_check_from_;
    const unsigned long long first = static_cast<unsigned long long>(std::ceil(10.0 * temper_tau_));
    if (drift_at_[1] ? s < 2 * drift_at_[1] : s < first) return;
    drift_theta_[0] = drift_theta_[1];
    drift_var_[0] = drift_var_[1];
    drift_at_[0] = drift_at_[1];
    for (Index i = 0; i < p_; ++i) {
        drift_theta_[1](i) = a_(nx_ + i) / scale_(nx_ + i);
        drift_var_[1](i) = P_(nx_ + i, nx_ + i);
    }
    drift_at_[1] = s;
}

double StandEkf::drift_z() const {
    if (!drift_at_[0]) return std::nan("");
    double z = 0.0;
    for (Index i = 0; i < p_; ++i) {
        const double v = P_(nx_ + i, nx_ + i), dv = std::max(drift_var_[0](i) - v, 1e-9 * drift_var_[0](i));
        z = std::max(z, std::fabs(a_(nx_ + i) / scale_(nx_ + i) - drift_theta_[0](i)) / std::sqrt(dv));
    }
    return z;
}

// Prediction over [t_k, t_{k+1}] (samples prev = k and cur = k+1), then the update.
vibid_status StandEkf::step(const double *prev, const double *cur) {
    const Index n = n_, nx = nx_;
    const double h = set_.h;
    const double s_k = base_disp(prev);
    if (set_.kf_rls) x_prev_ = a_.head(nx);  // the regression's start of the interval
    // xi0 = [x_k (+ kick); e_k; slopes]
    VecX &x0 = xi_[0];
    x0.setZero();
    x0.head(nx) = a_.head(nx);
    const Index eu = nx, ew = eu + r_ + nb_, e1 = ew + nw_;
    for (Index j = 0; j < r_; ++j) {
        const double uk = prev[input_ch_[static_cast<std::size_t>(j)]], uk1 = cur[input_ch_[static_cast<std::size_t>(j)]];
        x0(eu + j) = uk;
        x0(eu + ne_ + j) = input_smooth_[static_cast<std::size_t>(j)] ? (uk1 - uk) / h : 0.0;
    }
    double ds_kick = 0.0;
    if (nb_) {
        x0(col_s_) = s_k;
        if (col_sd_ >= 0) x0(col_sd_) = (base_disp(cur) - s_k) / h;  // smooth: linear over the interval
        if (held_base_kick_ && have_prev2_) ds_kick = s_k - base_disp(prev2_.data());  // held: a jump at t_k
    }
    if (nc_) x0(e1) = 1.0;
    kick_ds_ = ds_kick;
    if (held_base_kick_)
        for (Index i = 0; i < n; ++i) x0(n + i) += Minv_(i) * db_(i) * ds_kick;
    linearise_cubics(x0.data(), x0.data() + n, s_k, col_sd_ >= 0 ? x0(col_sd_) : 0.0);
    build_transition();
    T2_ = A_ * (h / 4.0);
    expm_small(T2_, E4_, T1_, Pow_);
    E2_.noalias() = E4_.lazyProduct(E4_);
    E1_.noalias() = E2_.lazyProduct(E2_);
    for (int j = 1; j <= 4; ++j) xi_[j].noalias() = E4_.lazyProduct(xi_[j - 1]);

    // Jacobian: F = [[Phi, J], [0, I]] in scaled coordinates.
    F_.setIdentity();
    for (Index i = 0; i < nx; ++i)
        for (Index j = 0; j < nx; ++j) F_(i, j) = E1_(i, j) * scale_(j) / scale_(i);
    static const double w[5] = {7.0, 32.0, 12.0, 32.0, 7.0};
    for (Index k = 0; k < nf_ - nx; ++k) {  // none for the KF+RLS
        const MatX &dA = dArows_[static_cast<std::size_t>(k)];
        acc_.setZero();
        for (int j = 0; j < 5; ++j) {
            if (j > 0) {
                T1_.col(0).noalias() = E4_.lazyProduct(acc_);
                acc_ = T1_.col(0);
            }
            gv_.noalias() = dA.lazyProduct(xi_[j]);
            acc_.segment(n, n) += w[j] * gv_;
        }
        acc_ *= h / 90.0;
        if (held_base_kick_ && ds_kick != 0.0) {
            // kick derivative d(M^-1 d_b)/d theta_k * ds, propagated by Phi
            const double *Mk = Mi_[static_cast<std::size_t>(k)].data();
            for (Index i = 0; i < n; ++i) {
                const double mi = Minv_(i);
                const double dkick = (-mi * mi * Mk[i] * db_(i) + mi * dbi_[static_cast<std::size_t>(k)](i)) * ds_kick;
                for (Index r = 0; r < nx; ++r) acc_(r) += E1_(r, n + i) * dkick;
            }
        }
        for (Index i = 0; i < nx; ++i) F_(i, nx + k) = acc_(i) * scale_(nx + k) / scale_(i);
    }
    // Predicted state.
    a_.head(nx) = xi_[4].head(nx);
    // Covariance: P = F P F' + Q; Q from the held disturbances, Gamma_w = columns of exp(A~ h).
    const Index nf = nf_;
    FP_.topLeftCorner(nf, nf).noalias() = F_.topLeftCorner(nf, nf).lazyProduct(P_.topLeftCorner(nf, nf));
    P_.topLeftCorner(nf, nf).noalias() =
        FP_.topLeftCorner(nf, nf).lazyProduct(F_.topLeftCorner(nf, nf).transpose());
    for (Index l = 0; l < nw_; ++l) {
        const double q = Rw_(l);
        for (Index i = 0; i < nx; ++i)
            for (Index j = 0; j < nx; ++j)
                P_(i, j) += q * E1_(i, ew + l) * E1_(j, ew + l) / (scale_(i) * scale_(j));
    }
    // The base channel's noise sigma^2: on s_k directly, on the slope as 2 sigma^2 / h^2
    // (correlation between neighbouring intervals neglected).
    if (nb_ && base_noise_var_ > 0.0) {
        const double vs = base_noise_var_, vd = 2.0 * base_noise_var_ / (h * h);
        for (Index i = 0; i < nx; ++i)
            for (Index j = 0; j < nx; ++j) {
                double q = vs * E1_(i, col_s_) * E1_(j, col_s_);
                if (col_sd_ >= 0) q += vd * E1_(i, col_sd_) * E1_(j, col_sd_);
                P_(i, j) += q / (scale_(i) * scale_(j));
            }
    }
    // Model-error allowance: each velocity may be off by kModelErrorVelocity of its
    // typical size per sample beyond what the model predicts. Without it the state of a
    // stand with measured inputs is a deterministic function of the parameters, the joint
    // covariance becomes singular (eigenvalues 1e-25 beside 1e-7 on a 2-DOF chain at
    // 10 kHz), and after a start 3 % or more off the filter kept a state error it
    // believed impossible: innovations 200 times the sensor noise for 100,000 samples,
    // then a restart. Real stands are never exactly their lumped model either.
    // The KF+RLS takes three times as much: its unmeasured states are the filter's alone
    // (no joint covariance with the parameters), and with wrong parameters and the EKF's
    // allowance they followed the wrong model. Measured on a 2-DOF base-excited stand with
    // the lower mass unmeasured (ident.ekf, c1 / d1 after 60 s): allowance x1: noise-free
    // -4.5 / -42 %, 1 % noise +0.26 / -1.3 %; x3: -2.4 / -2.3 %, +0.11 / -0.44 %;
    // x10: -0.26 / +5.1 %, +0.10 / +3.3 %; x30 and more: the damper 4-140 % off.
    const double qv = (set_.kf_rls ? 3.0 : 1.0) * kModelErrorVelocity;
    for (Index i = n; i < nx; ++i) P_(i, i) += qv * qv;
    if (set_.forgetting < 1.0 && !set_.kf_rls) P_.bottomRightCorner(p_, p_) /= set_.forgetting;
    symmetrise(P_);
    return update(cur);
}

// Measurement update with sample cur (at t_{k+1}). Leaves nu' S^-1 nu in last_nis_ and the
// Cholesky factor of S in Sz_. On a failure the state is not committed beyond the
// prediction; divergence is reported as VIBID_E_DIVERGED.
// Tempering of the measurement noise after a start (or restart, or the release of held
// parameters): R is inflated by kTemperStart, decaying with time constant temper_tau_
// to 1. With start values 20 % off, the innovations are 20-100 times the sensor noise;
// trusted at face value, the first updates linearised about wrong parameters overshoot
// into unstable parameter sets (a 3-DOF chain measured at its end diverged at every
// start from its nominal values). Gently weighted first, the data pull the parameters
// near the truth before they are trusted fully; afterwards the filter is the plain EKF.
// Measured on that chain: from the nominal values to within 0.1 % in 4 s, and the same
// final figures as a start from the truth.
// The KF+RLS needs none: its filter is linear in the states for given parameters, and
// the regression, not the filter, moves the parameters.
double StandEkf::temper() const {
    if (set_.kf_rls) return 1.0;
    if (release_at_ || !stats_.started) return kTemperStart;
    const double f = kTemperStart * std::exp(-static_cast<double>(stats_.n_steps - nis_check_from_) / temper_tau_);
    return f > 1.0 ? f : 1.0;
}

vibid_status StandEkf::update(const double *cur) {
    const Index n = n_, nx = nx_;
    double s = 0.0, sd = 0.0;
    base_now(cur, have_prev_ ? prev_.data() : nullptr, s, sd);
    const double *y = a_.data(), *v = a_.data() + n;
    Hm_.setZero();
    Rz_.setZero();
    for (Index k = 0; k < nz_; ++k) {
        const Meas &mm = meas_[static_cast<std::size_t>(k)];
        Rz_(k, k) = Rv_(k) * temper();
        const Index i = static_cast<Index>(mm.node);
        if (mm.q == 0) {
            zhat_(k) = y[i];
            Hm_(k, i) = scale_(i);
            continue;
        }
        if (mm.q == 1) {
            zhat_(k) = v[i];
            Hm_(k, n + i) = scale_(n + i);
            continue;
        }
        // acceleration: a_i = (f_i) / m_i, f = B u + c_b s + d_b s' - D v - C y - cubic
        double f = 0.0;
        for (Index j = 0; j < r_; ++j) f += B_(i, j) * cur[input_ch_[static_cast<std::size_t>(j)]];
        f += cb_(i) * s + db_(i) * sd;
        for (Index j = 0; j < n; ++j) f -= D_(i, j) * v[j] + C_(i, j) * y[j];
        for (std::size_t e = 0; e < cubics_.size(); ++e) {
            const Cubic &c = cubics_[e];
            const double eps = c.param >= 0 ? a_(nx + c.param) : c.value, rho = cubic_rho(e, y, s);
            const double sign = c.a == static_cast<std::size_t>(i) ? 1.0 : (c.b == static_cast<std::size_t>(i) ? -1.0 : 0.0);
            if (sign == 0.0) continue;
            f -= sign * eps * rho * rho * rho;
            const double k3 = 3.0 * eps * rho * rho;
            Hm_(k, static_cast<Index>(c.a)) -= sign * Minv_(i) * k3 * scale_(static_cast<Index>(c.a));
            if (c.b < static_cast<std::size_t>(n))
                Hm_(k, static_cast<Index>(c.b)) += sign * Minv_(i) * k3 * scale_(static_cast<Index>(c.b));

            if (c.param >= 0) Hm_(k, nx + c.param) -= sign * Minv_(i) * rho * rho * rho * scale_(nx + c.param);
        }
        const double acc = Minv_(i) * f;
        zhat_(k) = acc;
        for (Index j = 0; j < n; ++j) {
            Hm_(k, j) -= Minv_(i) * C_(i, j) * scale_(j);
            Hm_(k, n + j) -= Minv_(i) * D_(i, j) * scale_(n + j);
        }

        for (Index q = 0; q < p_; ++q) {
            const std::size_t qq = static_cast<std::size_t>(q);
            double df = 0.0;
            for (Index j = 0; j < r_; ++j) df += Bi_[qq](i, j) * cur[input_ch_[static_cast<std::size_t>(j)]];
            df += cbi_[qq](i) * s + dbi_[qq](i) * sd;
            for (Index j = 0; j < n; ++j) df -= Di_[qq](i, j) * v[j] + Ci_[qq](i, j) * y[j];
            Hm_(k, nx + q) += (Minv_(i) * df - Minv_(i) * Mi_[qq](i) * acc) * scale_(nx + q);
        }
        // A disturbance on this node is felt by its accelerometer directly: its held
        // value over [t_{k+1}, t_{k+2}) is independent of the state.
        for (Index l = 0; l < nw_; ++l)
            if (dist_node_[static_cast<std::size_t>(l)] == mm.node) Rz_(k, k) += Minv_(i) * Minv_(i) * Rw_(l);
    }
    for (Index k = 0; k < nz_; ++k) nu_(k) = cur[meas_[static_cast<std::size_t>(k)].channel] - zhat_(k);
    // Only the first nf coordinates take part (the KF+RLS's filter has no parameters).
    const Index nf = nf_;
    PHt_.topRows(nf).noalias() = P_.topLeftCorner(nf, nf).lazyProduct(Hm_.leftCols(nf).transpose());
    Sz_.noalias() = Hm_.leftCols(nf).lazyProduct(PHt_.topRows(nf));
    Sz_ += Rz_;
    for (Index k = 0; k < nz_; ++k) nu_sd_(k) = std::sqrt(std::max(Sz_(k, k), 0.0));
    nu_inflation_ = temper();
    if (!cholesky(Sz_)) return VIBID_FAIL(VIBID_E_DIVERGED, "innovation covariance not positive definite");
    // K = P H' S^-1, row by row through the factor.
    for (Index i = 0; i < nf; ++i) {
        // solve S x = (P H')_i^T
        for (Index k = 0; k < nz_; ++k) zhat_(k) = PHt_(i, k);
        chol_solve(Sz_, zhat_.data());
        for (Index k = 0; k < nz_; ++k) K_(i, k) = zhat_(k);
    }
    for (Index k = 0; k < nz_; ++k) zhat_(k) = nu_(k);
    const double q = chol_solve(Sz_, zhat_.data());  // nu' S^-1 nu
    last_nis_ = q;
    score_accumulate();  // before the state moves and P becomes P_k|k
    // State: a += T K nu
    for (Index i = 0; i < nf; ++i) {
        double d = 0.0;
        for (Index k = 0; k < nz_; ++k) d += K_(i, k) * nu_(k);
        a_(i) += scale_(i) * d;
    }
    // Joseph form: P = (I - K H) P (I - K H)' + K R K'
    auto IKH = IKH_.topLeftCorner(nf, nf);
    auto Pf = P_.topLeftCorner(nf, nf);
    auto FPf = FP_.topLeftCorner(nf, nf);
    auto KRf = PHt_.topRows(nf);
    IKH.setIdentity();
    IKH.noalias() -= K_.topRows(nf).lazyProduct(Hm_.leftCols(nf));
    FPf.noalias() = IKH.lazyProduct(Pf);
    Pf.noalias() = FPf.lazyProduct(IKH.transpose());
    KRf.noalias() = K_.topRows(nf).lazyProduct(Rz_);
    Pf.noalias() += KRf.lazyProduct(K_.topRows(nf).transpose());
    symmetrise(P_);
    stats_.nis_avg = set_.nis_memory * stats_.nis_avg + (1.0 - set_.nis_memory) * q / static_cast<double>(nz_);

    // Divergence: non-finite, a negative variance, a mass that is no longer positive,
    // a state far beyond its typical size, or innovations far beyond their covariance.
    for (Index i = 0; i < na_; ++i)
        if (!std::isfinite(a_(i)) || !(P_(i, i) >= 0.0) || !std::isfinite(P_(i, i)))
            return VIBID_FAIL(VIBID_E_DIVERGED, "filter diverged: non-finite state or covariance; restarted from the "
                                                "start values");
    for (Index i = 0; i < nx; ++i) {
        if (std::fabs(a_(i)) > 1e6 * scale_(i))
            return VIBID_FAIL(VIBID_E_DIVERGED, "filter diverged: state %ld beyond 1e6 times its typical size; "
                                                "restarted from the start values", static_cast<long>(i));
    }
    for (Index k = 0; k < p_; ++k)
        if (model_->terms[model_->param_term[static_cast<std::size_t>(k)]].kind == VIBID_PARAM_MASS &&
            !(a_(nx + k) > 0.0))
            return VIBID_FAIL(VIBID_E_DIVERGED, "filter diverged: mass '%s' reached %g; restarted from the start "
                                                "values",
                              model_->terms[model_->param_term[static_cast<std::size_t>(k)]].name.c_str(), a_(nx + k));
    // Innovations far beyond their covariance: the parameters changed (a crack) or the
    // filter lost them. First the parameters' covariance is widened (x100) so that they
    // can move to where the data are; only when that does not bring the innovations back
    // within five tries is it divergence.
    // Not while the parameters are held (their covariance is zero: widening it does
    // nothing, and wrong start values make the innovations large until they may move),
    // nor in the NIS average's own settling time after a start or release.
    const double settle = 1.0 / (1.0 - set_.nis_memory);
    if (stats_.nis_avg < 2.0) boosts_in_row_ = 0;
    if (!release_at_ && temper() <= 1.0 && static_cast<double>(stats_.n_steps - nis_check_from_) > settle &&
        stats_.nis_avg > set_.nis_limit) {
        if (boosts_in_row_ >= 5)
            return VIBID_FAIL(VIBID_E_DIVERGED, "filter diverged: averaged innovation NIS %.3g > %.3g after the "
                                                "parameters' covariance was widened 5 times; restarted from the start "
                                                "values",
                              stats_.nis_avg, set_.nis_limit);
        if (set_.kf_rls) {
            // the regression starts afresh about the current estimate
            for (Index i = 0; i < p_; ++i) rls_theta_(i) = a_(nx + i) / theta_start_(i);
            (void)vibid_rls_set_prior(rls_.get(), rls_theta_.data(), rls_P0_.data());
        } else {
            P_.bottomRightCorner(p_, p_) *= 100.0;
            P_.topRightCorner(nx, p_) *= 10.0;
            P_.bottomLeftCorner(p_, nx) *= 10.0;
        }
        stats_.nis_avg = 1.0;
        ++boosts_in_row_;
        ++stats_.boosts;
        drift_at_[0] = drift_at_[1] = 0;  // the covariance grew: the snapshots no longer bound the drift
    }
    return VIBID_OK;
}

// Before the start window is full an estimate is provisional: the filter runs over the
// samples so far (noise levels and all), its result is kept, and the filter goes back to
// collecting, so that the tracks do not depend on when (or how often) a caller asks: the
// start happens at the full window either way. The provisional run is repeated only when
// the window has grown by a quarter since the last one (about five times the window's
// samples of work in all); in between the last provisional result is returned.
vibid_status StandEkf::estimate(double *theta, double *se, double *cov) {
    if (!stats_.started) {
        if (n_window_ < 10)
            return VIBID_FAIL(VIBID_E_INSUFFICIENT_DATA, "%zu samples; the state-space estimator needs at least 10",
                              n_window_);
        if (4 * n_window_ >= 5 * prov_at_) {
            start_from_window();
            const Index nx = nx_;
            for (Index i = 0; i < p_; ++i) prov_theta_(i) = a_(nx + i);
            param_cov(prov_cov_);
            prov_stats_ = stats_;
            prov_stats_.started = false;
            prov_at_ = n_window_;
            stats_ = StandEkfStats{};
            have_prev_ = have_prev2_ = false;
        }
        for (Index i = 0; i < p_; ++i) {
            if (theta) theta[i] = prov_theta_(i);
            if (se) se[i] = std::sqrt(std::max(prov_cov_(i, i), 0.0));
            if (cov)
                for (Index j = 0; j < p_; ++j) cov[i + j * p_] = prov_cov_(i, j);
        }
        return VIBID_OK;
    }
    const Index nx = nx_;
    stats_.drift_z = drift_z();
    param_cov(cov_);
    const MatX &pc = cov_;
    for (Index i = 0; i < p_; ++i) {
        if (theta) theta[i] = a_(nx + i);
        if (se) se[i] = std::sqrt(std::max(pc(i, i), 0.0));
        if (cov)
            for (Index j = 0; j < p_; ++j) cov[i + j * p_] = pc(i, j);
    }
    return VIBID_OK;
}

// KF+RLS: one step of the regression on the physical parameters over [t_k, t_{k+1}]
// (samples prev, cur; the equation in stand_ekf.hpp). As in the paper's (3.16) the target
// is the filtered state x_{k+1|k+1} and the regressors depend on x_{k|k} only: the
// displacement terms are taken along the one-step prediction x_{k+1|k}. With the
// filtered end state in the regressors instead, its correction K nu_{k+1} appears on both
// sides and biases the regression (example 3: 22 % on c instead of a few); the
// prediction is orthogonal to nu_{k+1}. The inputs are taken as the filter's model takes
// them: smooth ones linear over the interval, held ones constant, a held base jumping by
// kick_ds_ at t_k.
void StandEkf::regression_step(const double *prev, const double *cur) {
    const Index n = n_, nx = nx_;
    const double h = set_.h;
    const VecX &pred = xi_[4];  // x_{k+1|k}
    for (Index i = 0; i < n; ++i) {
        const double y0 = x_prev_(i), y1 = pred(i), v1 = pred(n + i);
        const double v0p = xi_[0](n + i);  // after a held base's kick
        dv_(i) = a_(n + i) - x_prev_(n + i);
        dy_(i) = y1 - y0;
        iy_(i) = 0.5 * h * (y0 + y1) + h * h / 12.0 * (v0p - v1);  // cubic Hermite
    }
    for (Index j = 0; j < r_; ++j) {
        const std::size_t jj = static_cast<std::size_t>(j);
        const double uk = prev[input_ch_[jj]], uk1 = cur[input_ch_[jj]];
        iu_(j) = input_smooth_[jj] ? 0.5 * h * (uk + uk1) : h * uk;
    }
    const double s0 = base_disp(prev), s1 = base_smooth_ ? base_disp(cur) : s0;
    const double is = 0.5 * h * (s0 + s1), ds = base_smooth_ ? s1 - s0 : kick_ds_, sd = (s1 - s0) / h;
    // Known part into the target, each unknown's structure into its column.
    auto equation = [&](const VecX &Md, const MatX &Dm, const MatX &Cm, const MatX &Bm, const VecX &dbv,
                        const VecX &cbv, Index i) {
        double e = Md(i) * dv_(i) - dbv(i) * ds - cbv(i) * is;
        for (Index j = 0; j < n; ++j) e += Dm(i, j) * dy_(j) + Cm(i, j) * iy_(j);
        for (Index j = 0; j < r_; ++j) e -= Bm(i, j) * iu_(j);
        return e;
    };
    const Index nr = static_cast<Index>(rows_.size());
    for (Index q = 0; q < nr; ++q) {
        const Index i = rows_[static_cast<std::size_t>(q)];
        target_(q) = -equation(M0_, D0_, C0_, B0_, db0_, cb0_, i);
        for (Index k = 0; k < p_; ++k) {
            const std::size_t kk = static_cast<std::size_t>(k);
            phi_(k, q) = theta_start_(k) * equation(Mi_[kk], Di_[kk], Ci_[kk], Bi_[kk], dbi_[kk], cbi_[kk], i);
        }
    }
    // Cubic springs: int(rho^3) by Simpson's rule with the Hermite midpoint of rho.
    for (std::size_t e = 0; e < cubics_.size(); ++e) {
        const Cubic &c = cubics_[e];
        const double r0 = cubic_rho(e, x_prev_.data(), s0), r1 = cubic_rho(e, pred.data(), s1);
        auto rate = [&](const double *v, double base_rate) {
            const double vb = c.b == VIBID_GROUND ? 0.0 : c.b == VIBID_BASE ? base_rate : v[c.b];
            return v[c.a] - vb;
        };
        const double rd0 = rate(xi_[0].data() + n, base_smooth_ ? sd : 0.0),
                     rd1 = rate(pred.data() + n, base_smooth_ ? sd : 0.0);
        const double rm = 0.5 * (r0 + r1) + h / 8.0 * (rd0 - rd1);
        const double j3 = h / 6.0 * (r0 * r0 * r0 + 4.0 * rm * rm * rm + r1 * r1 * r1);
        for (Index q = 0; q < nr; ++q) {
            const Index i = rows_[static_cast<std::size_t>(q)];
            const double sign = static_cast<std::size_t>(i) == c.a ? 1.0 : static_cast<std::size_t>(i) == c.b ? -1.0 : 0.0;
            if (c.param >= 0)
                phi_(c.param, q) += sign * theta_start_(c.param) * j3;
            else
                target_(q) -= sign * c.value * j3;
        }
    }
    if (scale_pass_) {
        // equation error at the start values (scaled parameters 1)
        for (Index q = 0; q < nr; ++q) {
            const double e = phi_.col(q).sum() - target_(q);
            eq_(q) += e * e;
        }
        ++n_eq_;
        return;
    }
    for (Index q = 0; q < nr; ++q) {
        phi_.col(q) /= row_scale_(q);
        target_(q) /= row_scale_(q);
    }
    // A refused update (non-finite rows, breakdown) leaves the regression as it was; the
    // filter's checks report what caused it.
    if (vibid_rls_update(rls_.get(), phi_.data(), target_.data()) != VIBID_OK) return;
    (void)vibid_rls_theta(rls_.get(), rls_theta_.data());
    for (Index k = 0; k < p_; ++k) a_(nx + k) = theta_start_(k) * rls_theta_(k);
}

// ---------------------------------------------------------------------------------
// Sandwich covariance of the parameters (EKF without forgetting)
//
// The EKF's parameter update is a recursive prediction-error (Gauss-Newton) step:
// theta_k - theta_{k-1} = P_thth,k|k-1 psi_k S_k^-1 nu_k, psi_k = P_thth,k|k-1^-1 (P H')_theta
// the total derivative of the predicted measurements with respect to the parameters (through
// the states' covariance with them). So u_k = psi_k S_k^-1 nu_k is sample k's score,
// I_k = psi_k S_k^-1 psi_k' its information, and P_thth^-1 = P_0^-1 + sum I_k: the filter's
// error bars hold only when the scores are uncorrelated with covariance I_k, i.e. when the
// model, its process noise (the velocity allowance, step()) and the noise levels are right.
// The sandwich takes the scores' covariance from the data instead: G from the spread of
// their sums over B blocks of consecutive samples (correlation within a block counts),
// V = P G P. Each sample's score is taken at theta_{k-1}; moved to the final estimate
// theta_N to first order, u_k(theta_N) = u_k - I_k (theta_N - theta_{k-1}), so that the
// start transient's pull on the parameters does not count as spread: per block the sums of
// u_k, I_k and I_k theta_{k-1} are kept. p Cholesky solves of p and of nz per sample.

void StandEkf::score_reset() {
    sc_U_.setZero();
    sc_W_.setZero();
    for (auto &J : sc_J_) J.setZero();
    sc_blocks_ = 0;
    sc_len_ = kScoreBlockStart;
    sc_fill_ = sc_done_ = sc_skipped_ = 0;
}

// In update(), with P_ = P_k|k-1, PHt_ = P H', Sz_ the factor of S and zhat_ = S^-1 nu.
void StandEkf::score_accumulate() {
    if (set_.kf_rls || set_.forgetting < 1.0 || !stats_.started || release_at_) return;
    const Index nx = nx_, p = p_;
    sc_L_ = P_.bottomRightCorner(p, p);
    if (!cholesky(sc_L_)) {
        ++sc_skipped_;
        return;
    }
    for (Index k = 0; k < nz_; ++k) {  // psi = P_thth^-1 (P H')_theta
        for (Index i = 0; i < p; ++i) sc_u_(i) = PHt_(nx + i, k);
        chol_solve(sc_L_, sc_u_.data());
        sc_psi_.col(k) = sc_u_;
    }
    for (Index i = 0; i < p; ++i) {  // S^-1 psi'
        for (Index k = 0; k < nz_; ++k) sc_Spsi_(k, i) = sc_psi_(i, k);
        chol_solve(Sz_, sc_Spsi_.col(i).data());
    }
    sc_G_.noalias() = sc_psi_.lazyProduct(sc_Spsi_);  // I_k
    const Index b = sc_blocks_;
    for (Index i = 0; i < p; ++i) {
        double u = 0.0;
        for (Index k = 0; k < nz_; ++k) u += sc_psi_(i, k) * zhat_(k);
        sc_U_(i, b) += u;
        sc_th_(i) = a_(nx + i) / scale_(nx + i);
    }
    MatX &J = sc_J_[static_cast<std::size_t>(b)];
    J += sc_G_;
    for (Index i = 0; i < p; ++i) {
        double w = 0.0;
        for (Index j = 0; j < p; ++j) w += sc_G_(i, j) * sc_th_(j);
        sc_W_(i, b) += w;
    }
    if (++sc_fill_ < sc_len_) return;
    sc_done_ += sc_len_;
    sc_fill_ = 0;
    if (++sc_blocks_ < kScoreBlocks) return;
    // Full: merge neighbours, double the block length.
    const Index half = kScoreBlocks / 2;
    for (Index j = 0; j < half; ++j) {
        sc_U_.col(j) = sc_U_.col(2 * j) + sc_U_.col(2 * j + 1);
        sc_W_.col(j) = sc_W_.col(2 * j) + sc_W_.col(2 * j + 1);
        sc_J_[static_cast<std::size_t>(j)] =
            sc_J_[static_cast<std::size_t>(2 * j)] + sc_J_[static_cast<std::size_t>(2 * j + 1)];
    }
    for (Index j = half; j < kScoreBlocks; ++j) {
        sc_U_.col(j).setZero();
        sc_W_.col(j).setZero();
        sc_J_[static_cast<std::size_t>(j)].setZero();
    }
    sc_blocks_ = half;
    sc_len_ *= 2;
}

// V = P G P (scaled coordinates) into V; false (V untouched) with fewer than 16 completed
// blocks. G = B / (B - 1) sum_b (U_b - mean)(U_b - mean)', the U_b moved to the current
// estimate, times (samples scored) / (samples in completed blocks) for the current block's
// share (its partial sum would not be a sample of the same spread).
bool StandEkf::sandwich(MatX &V) {
    if (set_.kf_rls || set_.forgetting < 1.0 || sc_blocks_ < 16) return false;
    const Index nx = nx_, p = p_, B = sc_blocks_;
    for (Index i = 0; i < p; ++i) sc_th_(i) = a_(nx + i) / scale_(nx + i);
    auto moved = [&](Index b, VecX &out) {
        const MatX &J = sc_J_[static_cast<std::size_t>(b)];
        for (Index i = 0; i < p; ++i) {
            double s = sc_U_(i, b) + sc_W_(i, b);
            for (Index j = 0; j < p; ++j) s -= J(i, j) * sc_th_(j);
            out(i) = s;
        }
    };
    sc_w_.setZero();
    for (Index b = 0; b < B; ++b) {
        moved(b, sc_u_);
        sc_w_ += sc_u_;
    }
    sc_w_ /= static_cast<double>(B);
    sc_G_.setZero();
    for (Index b = 0; b < B; ++b) {
        moved(b, sc_u_);
        sc_u_ -= sc_w_;
        for (Index j = 0; j < p; ++j)
            for (Index i = 0; i < p; ++i) sc_G_(i, j) += sc_u_(i) * sc_u_(j);
    }
    const double share = static_cast<double>(sc_done_ + sc_fill_) / static_cast<double>(sc_done_);
    sc_G_ *= share * static_cast<double>(B) / static_cast<double>(B - 1);
    sc_L_.noalias() = P_.bottomRightCorner(p, p).lazyProduct(sc_G_);
    V.noalias() = sc_L_.lazyProduct(P_.bottomRightCorner(p, p));
    symmetrise(V);
    return true;
}

// Covariance of the parameters in physical units (p x p into cov): the filter's (EKF), or
// the regression's P times its residual variance (KF+RLS; the prior's units, residual
// variance 1, until the regression has more rows than parameters).
void StandEkf::param_cov(MatX &cov) {
    const Index nx = nx_;
    if (!set_.kf_rls) {
        stats_.robust = sandwich(sc_T_);
        stats_.robust_ratio = std::nan("");
        if (stats_.robust) {
            double worst = 0.0;
            for (Index i = 0; i < p_; ++i)
                if (P_(nx + i, nx + i) > 0.0) worst = std::max(worst, sc_T_(i, i) / P_(nx + i, nx + i));
            stats_.robust_ratio = worst;
        }
        // Never narrower than the filter's own: each parameter's row and column of P are
        // widened by sqrt(sandwich / filter variance) where that exceeds 1 (a congruence,
        // so the result stays a covariance). The sandwich alone was right in spread on
        // short runs (coverage 94 % on two stands, ident.ekf_coverage), but where the
        // filter's bars were too wide they also covered a bias of the estimate itself
        // (the 2-DOF base stand of ident.ekf over 60 s: d1 +0.96 %, filter se 0.8 %,
        // sandwich se 0.14 %), which the sandwich then left 7 standard errors out.
        for (Index i = 0; i < p_; ++i) {
            const double r = stats_.robust && P_(nx + i, nx + i) > 0.0 ? sc_T_(i, i) / P_(nx + i, nx + i) : 1.0;
            sc_w_(i) = r > 1.0 ? std::sqrt(r) : 1.0;
        }
        for (Index i = 0; i < p_; ++i)
            for (Index j = 0; j < p_; ++j)
                cov(i, j) = scale_(nx + i) * scale_(nx + j) * sc_w_(i) * sc_w_(j) * P_(nx + i, nx + j);
        return;
    }
    double s2 = 1.0;
    if (vibid_rls_residual_covariance(rls_.get(), &s2) != VIBID_OK || !(s2 >= 0.0)) s2 = 1.0;
    if (vibid_rls_covariance(rls_.get(), cov.data()) != VIBID_OK) cov.setConstant(std::nan(""));
    for (Index i = 0; i < p_; ++i)
        for (Index j = 0; j < p_; ++j) cov(i, j) *= s2 * theta_start_(i) * theta_start_(j);
}

}  // namespace vibid
