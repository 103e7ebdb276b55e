// simulate.cpp: the model at theta driven by a capture's measured inputs (vibid/simulate.h).
#include <vibid/simulate.h>

#include <Eigen/Dense>

#include "api_guard.hpp"
#include "model_internal.hpp"

#include <cmath>
#include <vector>

using vibid::throw_error;

namespace {

// Where the model's quantities are in the capture: a column index or -1.
struct Layout {
    std::vector<long> disp, vel;  // per node
    std::vector<long> input;      // per force input
    long base = -1, base_vel = -1;
    std::vector<vibid_channel_info> info;  // per channel
};

Layout layout_of(const vibid_model *model, const vibid_model_dims &dm) {
    Layout L;
    L.disp.assign(dm.n_dof, -1);
    L.vel.assign(dm.n_dof, -1);
    L.input.assign(dm.n_inputs, -1);
    L.info.resize(dm.n_channels);
    for (std::size_t c = 0; c < dm.n_channels; ++c) {
        vibid_channel_info &ci = L.info[c];
        if (vibid_model_channel_info(model, c, &ci) != VIBID_OK) throw_error(VIBID_E_STATE, "%s", vibid_last_error());
        const long col = static_cast<long>(c);
        if (ci.kind == VIBID_CHANNEL_INPUT) L.input[ci.index] = col;
        else if (ci.index == VIBID_BASE) {
            if (ci.kind == VIBID_CHANNEL_DISPLACEMENT) L.base = col;
            if (ci.kind == VIBID_CHANNEL_VELOCITY) L.base_vel = col;
        } else if (ci.kind == VIBID_CHANNEL_DISPLACEMENT) L.disp[ci.index] = col;
        else if (ci.kind == VIBID_CHANNEL_VELOCITY) L.vel[ci.index] = col;
    }
    if (dm.has_base && L.base < 0)
        throw_error(VIBID_E_DIMENSION,
                    "the stand's base moves but its displacement is not measured: no input to drive the model with");
    for (std::size_t j = 0; j < dm.n_inputs; ++j)
        if (L.input[j] < 0) throw_error(VIBID_E_DIMENSION, "input %zu has no channel", j);
    return L;
}

class Simulation {
public:
    Simulation(const vibid_model *model, const double *theta, double h, std::size_t N, const double *ch)
        : model_(model), theta_(theta), h_(h), N_(N), ch_(ch) {
        if (vibid_model_get_dims(model, &dm_) != VIBID_OK) throw_error(VIBID_E_STATE, "%s", vibid_last_error());
        n_ = dm_.n_dof;
        r_ = dm_.n_inputs;
        L_ = layout_of(model, dm_);
        // M^-1 at theta, once: every acceleration is M^-1 f
        Eigen::MatrixXd M(n_, n_);
        dbase_.assign(n_, 0.0);
        if (vibid_model_assemble(model, theta, M.data(), nullptr, nullptr, nullptr, dbase_.data(), nullptr) != VIBID_OK)
            throw_error(VIBID_E_STATE, "%s", vibid_last_error());
        Eigen::FullPivLU<Eigen::MatrixXd> lu(M);
        if (!lu.isInvertible()) throw_error(VIBID_E_NUMERICAL, "the mass matrix at these parameters is singular");
        Mi_ = lu.inverse();
        u_held_.assign(r_, false);
        for (std::size_t j = 0; j < r_; ++j) {
            vibid_hold hd;
            if (vibid_model_get_hold(model, j, &hd) == VIBID_OK) u_held_[j] = hd == VIBID_HOLD_ZOH;
        }
        if (dm_.has_base) {
            vibid_hold hd;
            if (vibid_model_get_hold(model, VIBID_BASE, &hd) == VIBID_OK) s_held_ = hd == VIBID_HOLD_ZOH;
        }
        u_.assign(r_, 0.0);
        f_.resize(static_cast<Eigen::Index>(n_));
    }

    vibid_status run(unsigned substeps, double *out) {
        const std::size_t nc = dm_.n_channels, n = n_;
        std::fill(out, out + N_ * nc, NAN);
        Eigen::VectorXd y = Eigen::VectorXd::Zero(n), yd = Eigen::VectorXd::Zero(n), acc(n);
        const std::size_t k0 = 2;
        for (std::size_t i = 0; i < n; ++i) {
            if (L_.disp[i] >= 0) y(i) = at(k0, L_.disp[i]);
            if (L_.vel[i] >= 0) yd(i) = at(k0, L_.vel[i]);
            else if (L_.disp[i] >= 0) yd(i) = slope(L_.disp[i], k0);
        }
        const Eigen::VectorXd kick = Mi_ * Eigen::Map<const Eigen::VectorXd>(dbase_.data(), n);
        std::vector<double> m0(1 + r_), m1(1 + r_);
        Eigen::VectorXd k1y(n), k1v(n), k2y(n), k2v(n), k3y(n), k3v(n), k4y(n), k4v(n), ty(n), tv(n);
        const double hs = h_ / substeps;
        vibid_status s = VIBID_OK;
        for (std::size_t k = k0; k < N_ && s == VIBID_OK; ++k) {
            slopes(k, m0);
            if (k + 1 < N_) slopes(k + 1, m1);
            else m1 = m0;
            if (s_held_ && k > k0) yd += kick * (at(k, L_.base) - at(k - 1, L_.base));  // the held base jumped at t_k
            inputs_at(k, 0.0, m0, m1);  // this sample's outputs
            s = accel(y, yd, acc);
            for (std::size_t c = 0; c < nc; ++c) {
                const vibid_channel_info &ci = L_.info[c];
                double v;
                if (ci.kind == VIBID_CHANNEL_INPUT || ci.index == VIBID_BASE) v = at(k, static_cast<long>(c));
                else if (ci.kind == VIBID_CHANNEL_DISPLACEMENT) v = y(static_cast<Eigen::Index>(ci.index));
                else if (ci.kind == VIBID_CHANNEL_VELOCITY) v = yd(static_cast<Eigen::Index>(ci.index));
                else v = acc(static_cast<Eigen::Index>(ci.index));
                out[k + c * N_] = v;
            }
            if (k + 1 >= N_) break;
            for (unsigned q = 0; q < substeps && s == VIBID_OK; ++q) {
                const double t0 = static_cast<double>(q) / substeps, tm = (q + 0.5) / substeps,
                             t1 = (q + 1.0) / substeps;
                inputs_at(k, t0, m0, m1);
                accel(y, yd, k1v);
                k1y = yd;
                ty = y + 0.5 * hs * k1y;
                tv = yd + 0.5 * hs * k1v;
                inputs_at(k, tm, m0, m1);
                accel(ty, tv, k2v);
                k2y = tv;
                ty = y + 0.5 * hs * k2y;
                tv = yd + 0.5 * hs * k2v;
                accel(ty, tv, k3v);
                k3y = tv;
                ty = y + hs * k3y;
                tv = yd + hs * k3v;
                inputs_at(k, t1, m0, m1);
                s = accel(ty, tv, k4v);
                k4y = tv;
                y += hs / 6.0 * (k1y + 2 * k2y + 2 * k3y + k4y);
                yd += hs / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v);
            }
        }
        return s;
    }

private:
    double at(std::size_t k, long c) const { return ch_[k + static_cast<std::size_t>(c) * N_]; }

    // Five-point central difference of column c at sample k (lower orders at the ends).
    double slope(long c, std::size_t k) const {
        if (k >= 2 && k + 2 < N_)
            return (at(k - 2, c) - 8.0 * at(k - 1, c) + 8.0 * at(k + 1, c) - at(k + 2, c)) / (12.0 * h_);
        if (k >= 1 && k + 1 < N_) return (at(k + 1, c) - at(k - 1, c)) / (2.0 * h_);
        return k == 0 ? (at(1, c) - at(0, c)) / h_ : (at(k, c) - at(k - 1, c)) / h_;
    }

    // Column c's cubic Hermite value and derivative at t_k + tau h, tau in [0, 1].
    void hermite(long c, std::size_t k, double tau, double m0, double m1, double *val, double *der) const {
        const double p0 = at(k, c), p1 = at(k + 1, c), h = h_;
        const double t2 = tau * tau, t3 = t2 * tau;
        *val = (2 * t3 - 3 * t2 + 1) * p0 + (t3 - 2 * t2 + tau) * h * m0 + (-2 * t3 + 3 * t2) * p1 + (t3 - t2) * h * m1;
        *der = ((6 * t2 - 6 * tau) * p0 + (3 * t2 - 4 * tau + 1) * h * m0 + (-6 * t2 + 6 * tau) * p1 +
                (3 * t2 - 2 * tau) * h * m1) / h;
    }

    // The inputs' slopes at sample k: [base, u_0 .. u_{r-1}].
    void slopes(std::size_t k, std::vector<double> &m) const {
        m[0] = dm_.has_base ? (L_.base_vel >= 0 ? at(k, L_.base_vel) : slope(L_.base, k)) : 0.0;
        for (std::size_t j = 0; j < r_; ++j) m[1 + j] = slope(L_.input[j], k);
    }

    // The inputs (u_, base_) at t_k + tau h.
    void inputs_at(std::size_t k, double tau, const std::vector<double> &m0, const std::vector<double> &m1) {
        for (std::size_t j = 0; j < r_; ++j) {
            double d;
            if (u_held_[j] || k + 1 >= N_) u_[j] = at(k, L_.input[j]);
            else hermite(L_.input[j], k, tau, m0[1 + j], m1[1 + j], &u_[j], &d);
        }
        if (!dm_.has_base) return;
        if (s_held_ || k + 1 >= N_) {
            base_[0] = at(k, L_.base);
            base_[1] = s_held_ ? 0.0 : m0[0];
        } else {
            hermite(L_.base, k, tau, m0[0], m1[0], &base_[0], &base_[1]);
        }
    }

    // a = M^-1 f(y, yd) with the inputs set by inputs_at.
    vibid_status accel(const Eigen::VectorXd &y, const Eigen::VectorXd &yd, Eigen::VectorXd &a) {
        const vibid_status s = vibid_model_forces(model_, theta_, y.data(), yd.data(), dm_.has_base ? base_ : nullptr,
                                                  r_ ? u_.data() : nullptr, f_.data());
        a.noalias() = Mi_ * f_;
        return s;
    }

    const vibid_model *model_;
    const double *theta_;
    double h_;
    std::size_t N_;
    const double *ch_;
    vibid_model_dims dm_{};
    std::size_t n_ = 0, r_ = 0;
    Layout L_;
    Eigen::MatrixXd Mi_;
    std::vector<double> dbase_;
    std::vector<bool> u_held_;
    bool s_held_ = false;
    std::vector<double> u_;
    double base_[2] = {0.0, 0.0};
    Eigen::VectorXd f_;
};

}  // namespace

extern "C" {

VIBID_API vibid_status vibid_model_simulate(const vibid_model *model, const double *theta, double sample_time,
                                            size_t n_samples, const double *channels, unsigned substeps,
                                            double *out) {
    VIBID_GUARD({
        if (!model || !theta || !channels || !out)
            throw_error(VIBID_E_NULL_ARGUMENT, "model, theta, channels and out are required");
        vibid::require_finalized(model);
        if (!(sample_time > 0.0) || !std::isfinite(sample_time))
            throw_error(VIBID_E_OUT_OF_RANGE, "sample_time = %g s must be > 0 and finite", sample_time);
        if (substeps < 1 || substeps > 1000) throw_error(VIBID_E_OUT_OF_RANGE, "substeps = %u outside 1..1000", substeps);
        if (n_samples < 5) throw_error(VIBID_E_INSUFFICIENT_DATA, "%zu samples: at least 5 are needed", n_samples);
        Simulation sim(model, theta, sample_time, n_samples, channels);
        return sim.run(substeps, out);
    });
}

}  // extern "C"
