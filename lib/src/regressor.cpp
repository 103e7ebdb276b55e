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
    unsigned order = 2;         // difference order: 2 (three-point, 1.17) or 4 (five-point)
    unsigned width = 3;         // samples in the window: order + 1
    unsigned centre = 1;        // age of the sample the equations describe
    // Ring of the last `width` samples' channels: slot (count - 1) % width is the newest.
    std::vector<double> window;
    unsigned long long count = 0;
    // window offset of the sample of each age (0 = newest), set by push: a sample's value is
    // read ~10 times per push, and a 64-bit modulo for each read was the regressor's largest
    // cost
    std::size_t age_offset[5] = {0, 0, 0, 0, 0};
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

// Channel value of sample `age` (0 = newest, 1 = previous, ...; < g.width).
inline double chan(const vibid_regressor &g, long channel, unsigned age) {
    return g.window[g.age_offset[age] + static_cast<std::size_t>(channel)];
}

// Value of `channel` at offset j from the centre sample (j = -2..2, j > 0 is newer).
inline double at(const vibid_regressor &g, long channel, int j) {
    return chan(g, channel, static_cast<unsigned>(static_cast<int>(g.centre) - j));
}

// First derivative at the centre: (1.17) for order 2, the five-point stencil
// (x_{c-2} - 8 x_{c-1} + 8 x_{c+1} - x_{c+2}) / 12h for order 4 (error h^4 x^(5) / 30).
inline double first_derivative(const vibid_regressor &g, long channel) {
    if (g.order == 2) return (at(g, channel, 1) - at(g, channel, -1)) / (2.0 * g.h);
    return (at(g, channel, -2) - 8.0 * at(g, channel, -1) + 8.0 * at(g, channel, 1) - at(g, channel, 2)) / (12.0 * g.h);
}

// Second derivative at the centre: (1.17), or the five-point stencil
// (-x_{c+2} + 16 x_{c+1} - 30 x_c + 16 x_{c-1} - x_{c-2}) / 12h^2 (error h^4 x^(6) / 90).
inline double second_derivative(const vibid_regressor &g, long channel) {
    if (g.order == 2) return (at(g, channel, 1) - 2.0 * at(g, channel, 0) + at(g, channel, -1)) / (g.h * g.h);
    return (-at(g, channel, 2) + 16.0 * at(g, channel, 1) - 30.0 * at(g, channel, 0) + 16.0 * at(g, channel, -1) -
            at(g, channel, -2)) /
           (12.0 * g.h * g.h);
}

// A held (ZOH) signal acts on the system like its sample sequence filtered by
// (1 - e^{-i w h}) / (i w h) = e^{-i w h/2} sinc(w h/2): delayed by half a sample and
// slightly low-passed (model.h, vibid_hold). Its equivalent smooth value at the centre:
// order 2: (s_{c-1} + s_c) / 2 (error (w h)^2 / 12); order 4: the four-tap fit
// (13 (s_{c-1} + s_c) - (s_{c-2} + s_{c+1})) / 24 (error O((w h)^4)). Its derivative is
// exactly (1 - e^{-i w h}) / h: the backward difference, the jump at t_c over h (the
// impulse a damper transmits).
inline double held_value(const vibid_regressor &g, long channel) {
    if (g.order == 2) return 0.5 * (at(g, channel, -1) + at(g, channel, 0));
    return (13.0 * (at(g, channel, -1) + at(g, channel, 0)) - (at(g, channel, -2) + at(g, channel, 1))) / 24.0;
}
inline double held_derivative(const vibid_regressor &g, long channel) {
    return (at(g, channel, 0) - at(g, channel, -1)) / g.h;
}

// Quantity q (0 disp, 1 vel, 2 acc) of a node or the base at the centre sample,
// measured when available, else differences of a lower quantity. A held base
// displacement gives its hold equivalents (its acceleration is never needed: the base
// has no mass).
inline double centre_quantity(const vibid_regressor &g, std::size_t node, int q) {
    if (node == VIBID_GROUND) return 0.0;
    const std::array<long, 3> &ch = node == VIBID_BASE ? g.model.base_channel : g.model.node_channel[node];
    if (node == VIBID_BASE && g.model.base_hold == VIBID_HOLD_ZOH && q < 2 && ch[0] != vibid::kNoChannel)
        return q == 0 ? held_value(g, ch[0]) : held_derivative(g, ch[0]);
    if (ch[q] != vibid::kNoChannel) return at(g, ch[q], 0);
    if (q == 1) return first_derivative(g, ch[0]);
    // q == 2
    if (ch[1] != vibid::kNoChannel) return first_derivative(g, ch[1]);
    return second_derivative(g, ch[0]);
}

// Force input j in equation row `row`. A held input is replaced by its hold equivalent,
// except in the equation of a node whose acceleration is measured: an accelerometer
// sampled at t_k sees the force that holds from t_k (the instantaneous equation), so
// there the sample itself is consistent.
inline double input_value(const vibid_regressor &g, std::size_t j, std::size_t row) {
    const long c = g.model.input_channel[j];
    if (g.model.inputs[j].hold != VIBID_HOLD_ZOH) return at(g, c, 0);
    if (row < g.n && g.model.node_channel[row][2] != vibid::kNoChannel) return at(g, c, 0);
    return held_value(g, c);
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
            case SignalType::Input: val = input_value(g, s.a, e.row); break;
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
    return vibid_regressor_create_order(model, sample_time, prefilter_hz, 2);
}

VIBID_API vibid_regressor *vibid_regressor_create_order(const vibid_model *model, double sample_time,
                                                        double prefilter_hz, unsigned difference_order) {
    return vibid::guard_create<vibid_regressor>(__func__, [&] {
        if (difference_order != 2 && difference_order != 4)
            throw_error(VIBID_E_OUT_OF_RANGE, "difference_order = %u: use 2 (1.17) or 4 (five-point stencils)",
                        difference_order);
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
        // ZOH builds (1.16) from three consecutive samples whatever the order.
        g->order = g->zoh ? 2 : difference_order;
        g->width = g->order + 1;
        g->centre = g->order / 2;
        g->window.assign(g->width * g->n_channels, 0.0);
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
    dims->latency = reg->zoh ? 0 : reg->centre;
    return VIBID_OK;
}

// Real-time path: no exceptions, no allocation.
VIBID_API vibid_status vibid_regressor_push(vibid_regressor *reg, const double *channels, double *x, double *y,
                                            int *ready) {
    if (!reg || !channels || !x || !y || !ready)
        return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "reg, channels, x, y and ready are required");
    if (!vibid::all_finite(channels, reg->n_channels)) return VIBID_FAIL(VIBID_E_NONFINITE, "channel with NaN or Inf");
    const std::size_t slot = static_cast<std::size_t>(reg->count % reg->width);
    for (std::size_t i = 0; i < reg->n_channels; ++i) reg->window[slot * reg->n_channels + i] = channels[i];
    ++reg->count;
    if (reg->count < reg->width) {
        *ready = 0;
        return VIBID_OK;
    }
    for (unsigned age = 0, s = static_cast<unsigned>(slot); age < reg->width; ++age, s = s ? s - 1 : reg->width - 1)
        reg->age_offset[age] = s * reg->n_channels;
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
