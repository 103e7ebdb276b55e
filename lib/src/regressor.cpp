// regressor.cpp: per-sample regressor builder (central differences (1.17) on the
// structured form (4.1), or the second-order difference form (1.16) for ZOH), with the
// optional Butterworth pre-filter. Everything is sized in create; push allocates nothing.
#include <vibid/regressor.h>

#include "api_guard.hpp"
#include "model_internal.hpp"

#include <cmath>
#include <algorithm>
#include <memory>
#include <vector>

using vibid::Signal;
using vibid::SignalType;
using vibid::throw_error;

namespace {

// Direct-form-II-transposed biquad, normalised a0 = 1.
struct Biquad {
    double b0, b1, b2, a1, a2;
};

// One column's filter state: two cascaded biquads, two delays each.
struct FilterState {
    double z[4];
};

}  // namespace

struct vibid_regressor {
    vibid_model model;
    double h = 0.0;
    double prefilter_hz = 0.0;
    std::size_t n = 0, r = 0, n_channels = 0;
    std::size_t p_reg = 0, m_eq = 0, q_out = 0;
    bool zoh = false;
    // Ring of the last 3 samples' channels: slot (count - 1) % 3 is the newest.
    std::vector<double> window;
    unsigned long long count = 0;
    // Pre-filter
    bool filter_on = false;
    Biquad section[2]{};
    std::vector<FilterState> state;  // one per column of x (p_reg * m) and y (m * q)
};

namespace {

// 4th-order Butterworth low-pass as two biquads (bilinear transform with pre-warping,
// the RBJ audio-EQ form): Q = 1 / (2 cos(pi/8)) and 1 / (2 cos(3 pi/8)).
void design_butterworth4(double fc, double h, Biquad out[2]) {
    const double w0 = 2.0 * M_PI * fc * h;
    const double cw = std::cos(w0), sw = std::sin(w0);
    const double qs[2] = {1.0 / (2.0 * std::cos(M_PI / 8.0)), 1.0 / (2.0 * std::cos(3.0 * M_PI / 8.0))};
    for (int i = 0; i < 2; ++i) {
        const double alpha = sw / (2.0 * qs[i]);
        const double a0 = 1.0 + alpha;
        out[i].b0 = (1.0 - cw) / 2.0 / a0;
        out[i].b1 = (1.0 - cw) / a0;
        out[i].b2 = (1.0 - cw) / 2.0 / a0;
        out[i].a1 = -2.0 * cw / a0;
        out[i].a2 = (1.0 - alpha) / a0;
    }
}

inline double filter_step(const Biquad sec[2], FilterState &st, double x) {
    double v = x;
    for (int i = 0; i < 2; ++i) {
        const double out = sec[i].b0 * v + st.z[2 * i];
        st.z[2 * i] = sec[i].b1 * v - sec[i].a1 * out + st.z[2 * i + 1];
        st.z[2 * i + 1] = sec[i].b2 * v - sec[i].a2 * out;
        v = out;
    }
    return v;
}

void reset_state(vibid_regressor &g) {
    g.count = 0;
    std::fill(g.window.begin(), g.window.end(), 0.0);
    for (auto &s : g.state) s = FilterState{{0.0, 0.0, 0.0, 0.0}};
}

// Channel value of sample `age` (0 = newest, 1 = previous, 2 = the one before).
inline double chan(const vibid_regressor &g, long channel, unsigned age) {
    const unsigned long long slot = (g.count - 1 - age) % 3;
    return g.window[slot * g.n_channels + static_cast<std::size_t>(channel)];
}

// Quantity q (0 disp, 1 vel, 2 acc) of a node or the base at the centre sample (age 1),
// measured when available, else central differences (1.17) of a lower quantity.
inline double centre_quantity(const vibid_regressor &g, std::size_t node, int q) {
    if (node == VIBID_GROUND) return 0.0;
    const std::array<long, 3> &ch = node == VIBID_BASE ? g.model.base_channel : g.model.node_channel[node];
    if (ch[q] != vibid::kNoChannel) return chan(g, ch[q], 1);
    const double h = g.h;
    if (q == 1) return (chan(g, ch[0], 0) - chan(g, ch[0], 2)) / (2.0 * h);
    // q == 2
    if (ch[1] != vibid::kNoChannel) return (chan(g, ch[1], 0) - chan(g, ch[1], 2)) / (2.0 * h);
    return (chan(g, ch[0], 0) - 2.0 * chan(g, ch[0], 1) + chan(g, ch[0], 2)) / (h * h);
}

void build_structured(const vibid_regressor &g, double *x, double *y) {
    const std::size_t p = g.p_reg;
    for (std::size_t i = 0; i < p * g.m_eq; ++i) x[i] = 0.0;
    for (std::size_t i = 0; i < g.m_eq; ++i) y[i] = 0.0;
    for (const auto &t : g.model.terms) {
        for (const auto &e : t.entries) {
            const Signal &s = e.signal;
            double val;
            switch (s.type) {
            case SignalType::Input: val = chan(g, g.model.input_channel[s.a], 1); break;
            case SignalType::Displacement: val = centre_quantity(g, s.a, 0) - centre_quantity(g, s.b, 0); break;
            case SignalType::Velocity: val = centre_quantity(g, s.a, 1) - centre_quantity(g, s.b, 1); break;
            case SignalType::Acceleration: val = centre_quantity(g, s.a, 2) - centre_quantity(g, s.b, 2); break;
            case SignalType::Cubic: {
                const double rel = centre_quantity(g, s.a, 0) - centre_quantity(g, s.b, 0);
                val = rel * rel * rel;
                break;
            }
            default: val = 0.0;
            }
            if (t.unknown)
                x[static_cast<std::size_t>(t.param) + e.row * p] += e.coef * val;
            else
                y[e.row] -= t.value * e.coef * val;
        }
    }
}

// x = [y_{k-1}; y_{k-2}; v_{k-1}; v_{k-2}] (p_reg x 1), y = y_k^T (1 x n).
void build_zoh(const vibid_regressor &g, double *x, double *y) {
    const std::size_t n = g.n, rz = (g.p_reg - 2 * n) / 2;
    for (std::size_t i = 0; i < n; ++i) {
        const long c = g.model.node_channel[i][0];
        y[i] = chan(g, c, 0);
        x[i] = chan(g, c, 1);
        x[n + i] = chan(g, c, 2);
    }
    for (std::size_t j = 0; j < rz; ++j) {
        const long c = j < g.r ? g.model.input_channel[j] : g.model.base_channel[0];
        x[2 * n + j] = chan(g, c, 1);
        x[2 * n + rz + j] = chan(g, c, 2);
    }
}

}  // namespace

extern "C" {

VIBID_API vibid_regressor *vibid_regressor_create(const vibid_model *model, double sample_time,
                                                  double prefilter_hz) {
    return vibid::guard_create<vibid_regressor>(__func__, [&] {
        vibid::require_finalized(model);
        if (!(sample_time > 0.0) || !std::isfinite(sample_time))
            throw_error(VIBID_E_OUT_OF_RANGE, "sample_time = %g s must be > 0 and finite", sample_time);
        if (!(prefilter_hz >= 0.0) || !std::isfinite(prefilter_hz) || prefilter_hz >= 0.45 / sample_time)
            throw_error(VIBID_E_OUT_OF_RANGE, "prefilter_hz = %g must be 0 (off) or in (0, %g) (0.45 f_a)",
                        prefilter_hz, 0.45 / sample_time);
        vibid::check_signals_available(*model);
        auto g = std::make_unique<vibid_regressor>();
        g->model = *model;
        g->h = sample_time;
        g->prefilter_hz = prefilter_hz;
        g->n = model->nodes.size();
        g->r = model->inputs.size();
        g->n_channels = model->channels.size();
        g->zoh = model->discretization == VIBID_DISC_ZOH;
        if (g->zoh) {
            const std::size_t rz = g->r + (model->has_base ? 1 : 0);
            g->p_reg = 2 * g->n + 2 * rz;
            g->m_eq = 1;
            g->q_out = g->n;
        } else {
            g->p_reg = model->param_term.size();
            if (g->p_reg == 0) throw_error(VIBID_E_OUT_OF_RANGE, "nothing unknown: the regressor would be empty");
            g->m_eq = g->n;
            g->q_out = 1;
        }
        g->window.assign(3 * g->n_channels, 0.0);
        g->filter_on = prefilter_hz > 0.0;
        if (g->filter_on) {
            design_butterworth4(prefilter_hz, sample_time, g->section);
            g->state.assign(g->p_reg * g->m_eq + g->m_eq * g->q_out, FilterState{{0, 0, 0, 0}});
        }
        reset_state(*g);
        return g.release();
    });
}

VIBID_API vibid_status vibid_regressor_reset(vibid_regressor *reg) {
    if (!reg) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "reg is NULL");
    reset_state(*reg);
    return VIBID_OK;
}

VIBID_API void vibid_regressor_destroy(vibid_regressor *reg) { delete reg; }

VIBID_API vibid_status vibid_regressor_get_dims(const vibid_regressor *reg, vibid_regressor_dims *dims) {
    if (!reg || !dims) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "reg and dims are required");
    dims->n_regressors = reg->p_reg;
    dims->n_equations = reg->m_eq;
    dims->n_outputs = reg->q_out;
    dims->latency = reg->zoh ? 0 : 1;
    return VIBID_OK;
}

// Real-time path: no exceptions, no allocation.
VIBID_API vibid_status vibid_regressor_push(vibid_regressor *reg, const double *channels, double *x, double *y,
                                            int *ready) {
    if (!reg || !channels || !x || !y || !ready)
        return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "reg, channels, x, y and ready are required");
    if (!vibid::all_finite(channels, reg->n_channels)) return VIBID_FAIL(VIBID_E_NONFINITE, "channel with NaN or Inf");
    const std::size_t slot = static_cast<std::size_t>(reg->count % 3);
    for (std::size_t i = 0; i < reg->n_channels; ++i) reg->window[slot * reg->n_channels + i] = channels[i];
    ++reg->count;
    if (reg->count < 3) {
        *ready = 0;
        return VIBID_OK;
    }
    if (reg->zoh)
        build_zoh(*reg, x, y);
    else
        build_structured(*reg, x, y);
    if (reg->filter_on) {
        const std::size_t nx = reg->p_reg * reg->m_eq, ny = reg->m_eq * reg->q_out;
        for (std::size_t i = 0; i < nx; ++i) x[i] = filter_step(reg->section, reg->state[i], x[i]);
        for (std::size_t i = 0; i < ny; ++i) y[i] = filter_step(reg->section, reg->state[nx + i], y[i]);
    }
    *ready = 1;
    return VIBID_OK;
}

}  // extern "C"
