// regressor.cpp: per-sample regressor builder (central differences (1.17) on the
// structured form (4.1), or the second-order difference form (1.16) for ZOH), with the
// optional Butterworth pre-filter. Everything is sized in create; push allocates nothing.
//
// Compiled at create. In the structured form every entry of x and y is a fixed linear
// combination of the window's sample values: the stencils (1/h and 1/h^2 included), hold
// equivalents, entry coefficients and the known terms' values all multiply out at create
// into one sparse coefficient matrix (entries of x and y by window values, in blocks of four
// entries), except the cubic entries, each the cube of such a combination (a short list of
// taps). A push is then one small matrix-vector product over the window, the cubic list,
// and the pre-filter on all entries at once (kernels.hpp, RegStep; AVX2 where the CPU has
// it). Walking the model's terms per sample, with a stencil recomputed for each entry, cost
// 2.3 times as much on paper example 1 (45 against 20 ns per push with the pre-filter). The
// arithmetic differs from that walk only in the order of rounding:
// tests/lib/test_regressor_compiled.cpp keeps the walk as its reference.
#include <vibid/regressor.h>

#include "api_guard.hpp"
#include "kernels.hpp"
#include "model_internal.hpp"
#include "regressor_internal.hpp"

#include <algorithm>
#include <cmath>
#include <memory>
#include <utility>
#include <vector>

using vibid::Signal;
using vibid::SignalType;
using vibid::throw_error;
using vibid::kern::idx;

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
    // Ring of the last `width` samples' channels: slot `newest` holds the newest sample,
    // slot (newest - age) mod width the sample of that age.
    std::vector<double> window;
    unsigned long long count = 0;
    unsigned newest = 0;
    // window offset of the sample of each age (0 = newest), for build_zoh; set by push
    std::size_t age_offset[5] = {0, 0, 0, 0, 0};
    // Compiled structured form (see the file comment and RegStep). The weights do not depend
    // on where the ring stands; the window index of each column does: one list of n_cols
    // indices per position of the newest slot.
    std::size_t nx = 0, ny = 0;     // entries of x (p_reg m) and y (m q)
    std::size_t n_pad = 0;          // nx + ny rounded up to a multiple of 4 (RegStep)
    std::size_t n_cols = 0;         // columns: the blocks' window values, then the cubic taps
    std::vector<double> A;          // 4 weights per block column
    std::vector<idx> block;         // n_pad / 4 + 1: first column of each block
    std::vector<idx> col;           // width x n_cols
    std::vector<vibid::kern::RegCubic> cubic;
    std::vector<double> out;        // n_pad: x, then y, then zeros
    // Pre-filter: two biquads (b0 b1 b2 a1 a2 each), delays 4 x n_pad (RegStep::z)
    bool filter_on = false;
    double section[10] = {};
    std::vector<double> z;
    vibid::kern::RegStep step{};
    const vibid::kern::Table *kt = nullptr;
    // A constant column (1 in every row) after the same pre-filter from the same restart:
    // the regressor of a constant force (identify.cpp). Its biquad delays, and its value in
    // the last row built.
    double unit_z[4] = {0.0, 0.0, 0.0, 0.0};
    double unit = 1.0;
};

namespace {

// 4th-order Butterworth low-pass as two biquads (bilinear transform with pre-warping,
// the RBJ audio-EQ form): Q = 1 / (2 cos(pi/8)) and 1 / (2 cos(3 pi/8)).
// out: b0 b1 b2 a1 a2 of each section, normalised a0 = 1.
void design_butterworth4(double fc, double h, double out[10]) {
    const double w0 = 2.0 * M_PI * fc * h;
    const double cw = std::cos(w0), sw = std::sin(w0);
    const double qs[2] = {1.0 / (2.0 * std::cos(M_PI / 8.0)), 1.0 / (2.0 * std::cos(3.0 * M_PI / 8.0))};
    for (int i = 0; i < 2; ++i) {
        const double alpha = sw / (2.0 * qs[i]);
        const double a0 = 1.0 + alpha;
        double *c = out + 5 * i;
        c[0] = (1.0 - cw) / 2.0 / a0;
        c[1] = (1.0 - cw) / a0;
        c[2] = (1.0 - cw) / 2.0 / a0;
        c[3] = -2.0 * cw / a0;
        c[4] = (1.0 - alpha) / a0;
    }
}

void reset_state(vibid_regressor &g) {
    g.count = 0;
    g.newest = g.width - 1;  // the first push goes to slot 0
    std::fill(g.window.begin(), g.window.end(), 0.0);
    std::fill(g.z.begin(), g.z.end(), 0.0);
    std::fill(g.unit_z, g.unit_z + 4, 0.0);
    g.unit = 1.0;
}

// ---- the structured form, compiled: stencils as weights over the window ----

// A linear combination of window values: (value, weight) pairs, the value indexed
// age * n_channels + channel (age 0 = newest) while compiling. Sparse: an entry reads at
// most a few values, the window of a large model has hundreds.
struct Combination {
    std::vector<std::pair<std::size_t, double>> terms;
    void add(std::size_t v, double w) {
        for (auto &t : terms)
            if (t.first == v) {
                t.second += w;
                return;
            }
        terms.emplace_back(v, w);
    }
};

struct Compiler {
    const vibid_regressor &g;

    // w times the value of `channel` at offset j from the centre sample (j = -2..2, j > 0
    // is newer).
    void at(Combination &c, long channel, int j, double w) const {
        const std::size_t age = static_cast<std::size_t>(static_cast<int>(g.centre) - j);
        c.add(age * g.n_channels + static_cast<std::size_t>(channel), w);
    }

    // First derivative at the centre: (1.17) for order 2, the five-point stencil
    // (x_{c-2} - 8 x_{c-1} + 8 x_{c+1} - x_{c+2}) / 12h for order 4 (error h^4 x^(5) / 30).
    void first_derivative(Combination &c, long ch, double w) const {
        if (g.order == 2) {
            const double s = w / (2.0 * g.h);
            at(c, ch, 1, s);
            at(c, ch, -1, -s);
            return;
        }
        const double s = w / (12.0 * g.h);
        at(c, ch, -2, s);
        at(c, ch, -1, -8.0 * s);
        at(c, ch, 1, 8.0 * s);
        at(c, ch, 2, -s);
    }

    // Second derivative at the centre: (1.17), or the five-point stencil
    // (-x_{c+2} + 16 x_{c+1} - 30 x_c + 16 x_{c-1} - x_{c-2}) / 12h^2 (error h^4 x^(6) / 90).
    void second_derivative(Combination &c, long ch, double w) const {
        if (g.order == 2) {
            const double s = w / (g.h * g.h);
            at(c, ch, 1, s);
            at(c, ch, 0, -2.0 * s);
            at(c, ch, -1, s);
            return;
        }
        const double s = w / (12.0 * g.h * g.h);
        at(c, ch, 2, -s);
        at(c, ch, 1, 16.0 * s);
        at(c, ch, 0, -30.0 * s);
        at(c, ch, -1, 16.0 * s);
        at(c, ch, -2, -s);
    }

    // A held (ZOH) signal acts on the system like its sample sequence filtered by
    // (1 - e^{-i w h}) / (i w h) = e^{-i w h/2} sinc(w h/2): delayed by half a sample and
    // slightly low-passed (model.h, vibid_hold). Its equivalent smooth value at the centre:
    // order 2: (s_{c-1} + s_c) / 2 (error (w h)^2 / 12); order 4: the four-tap fit
    // (13 (s_{c-1} + s_c) - (s_{c-2} + s_{c+1})) / 24 (error O((w h)^4)). Its derivative is
    // exactly (1 - e^{-i w h}) / h: the backward difference, the jump at t_c over h (the
    // impulse a damper transmits).
    void held_value(Combination &c, long ch, double w) const {
        if (g.order == 2) {
            at(c, ch, -1, 0.5 * w);
            at(c, ch, 0, 0.5 * w);
            return;
        }
        const double s = w / 24.0;
        at(c, ch, -1, 13.0 * s);
        at(c, ch, 0, 13.0 * s);
        at(c, ch, -2, -s);
        at(c, ch, 1, -s);
    }
    void held_derivative(Combination &c, long ch, double w) const {
        at(c, ch, 0, w / g.h);
        at(c, ch, -1, -w / g.h);
    }

    // Quantity q (0 disp, 1 vel, 2 acc) of a node or the base at the centre sample,
    // measured when available, else differences of a lower quantity. A held base
    // displacement gives its hold equivalents (its acceleration is never needed: the base
    // has no mass). vibid::check_signals_available has made sure the channels exist.
    void centre_quantity(Combination &c, std::size_t node, int q, double w) const {
        if (node == VIBID_GROUND) return;
        const std::array<long, 3> &ch = node == VIBID_BASE ? g.model.base_channel : g.model.node_channel[node];
        if (node == VIBID_BASE && g.model.base_hold == VIBID_HOLD_ZOH && q < 2 && ch[0] != vibid::kNoChannel) {
            if (q == 0)
                held_value(c, ch[0], w);
            else
                held_derivative(c, ch[0], w);
        } else if (ch[q] != vibid::kNoChannel) {
            at(c, ch[q], 0, w);
        } else if (q == 1) {
            first_derivative(c, ch[0], w);
        } else if (ch[1] != vibid::kNoChannel) {  // q == 2
            first_derivative(c, ch[1], w);
        } else {
            second_derivative(c, ch[0], w);
        }
    }

    // Force input j in equation row `row`. A held input is replaced by its hold equivalent,
    // except in the equation of a node whose acceleration is measured: an accelerometer
    // sampled at t_k sees the force that holds from t_k (the instantaneous equation), so
    // there the sample itself is consistent.
    void input_value(Combination &c, std::size_t j, std::size_t row, double w) const {
        const long ch = g.model.input_channel[j];
        if (g.model.inputs[j].hold != VIBID_HOLD_ZOH ||
            (row < g.n && g.model.node_channel[row][2] != vibid::kNoChannel))
            at(c, ch, 0, w);
        else
            held_value(c, ch, w);
    }

    // w times signal s of an entry in equation row `row` (s not Cubic).
    void signal(Combination &c, const Signal &s, std::size_t row, double w) const {
        if (s.type == SignalType::Input) {
            input_value(c, s.a, row, w);
            return;
        }
        const int q = s.type == SignalType::Velocity ? 1 : s.type == SignalType::Acceleration ? 2 : 0;
        centre_quantity(c, s.a, q, w);
        centre_quantity(c, s.b, q, -w);
    }
};

// Fills A, col, block and cubic from the model's terms: entry e of term t adds
// coef * signal to its column of x (t unknown) or -value * coef * signal to its row of y
// (t known). The entries of out are taken in blocks of four, each with the window values
// that its entries read (RegStep): work and memory grow like the entries' taps (n^2 for a
// chain of n masses), not like entries x window (n^3).
void compile_structured(vibid_regressor &g) {
    const std::size_t p = g.p_reg, nc = g.n_channels;
    const Compiler cc{g};
    std::vector<Combination> rows(g.n_pad);
    struct Cubic {
        std::size_t out;
        double coef;
        Combination rel;
    };
    std::vector<Cubic> cubics;
    for (const auto &t : g.model.terms) {
        for (const auto &e : t.entries) {
            const std::size_t out = t.unknown ? static_cast<std::size_t>(t.param) + e.row * p : g.nx + e.row;
            const double w = t.unknown ? e.coef : -(t.value * e.coef);
            if (e.signal.type == SignalType::Cubic) {
                Cubic cu{out, w, {}};
                cc.centre_quantity(cu.rel, e.signal.a, 0, 1.0);
                cc.centre_quantity(cu.rel, e.signal.b, 0, -1.0);
                cubics.push_back(std::move(cu));
            } else {
                cc.signal(rows[out], e.signal, e.row, w);
            }
        }
    }
    // Blocks: the window values (in window order) read by any of the block's four entries,
    // and their four weights each. Weights that cancelled to zero read nothing.
    std::vector<std::size_t> value;  // window value of each column, all blocks
    g.A.clear();
    g.block.assign(1, 0);
    for (std::size_t b = 0; b < g.n_pad; b += 4) {
        std::vector<std::size_t> vs;
        for (std::size_t i = b; i < b + 4; ++i)
            for (const auto &t : rows[i].terms)
                if (t.second != 0.0) vs.push_back(t.first);
        std::sort(vs.begin(), vs.end());
        vs.erase(std::unique(vs.begin(), vs.end()), vs.end());
        for (std::size_t v : vs) {
            value.push_back(v);
            for (std::size_t i = b; i < b + 4; ++i) {
                double w = 0.0;
                for (const auto &t : rows[i].terms)
                    if (t.first == v) w = t.second;
                g.A.push_back(w);
            }
        }
        g.block.push_back(static_cast<idx>(value.size()));
    }
    // Cubic taps read their values through col too, after the blocks' columns.
    g.cubic.clear();
    for (const auto &cu : cubics) {
        vibid::kern::RegCubic rc{};
        rc.out = static_cast<idx>(cu.out);
        rc.coef = cu.coef;
        for (const auto &t : cu.rel.terms) {
            if (t.second == 0.0) continue;
            if (rc.n_taps == vibid::kern::kCubicTaps)
                throw_error(VIBID_E_UNSUPPORTED, "cubic entry with more than %td window values",
                            vibid::kern::kCubicTaps);
            rc.tap[rc.n_taps] = static_cast<idx>(value.size());
            rc.w[rc.n_taps] = t.second;
            ++rc.n_taps;
            value.push_back(t.first);
        }
        g.cubic.push_back(rc);
    }
    // Window index of each column for each position of the ring (RegStep::col).
    const std::size_t ncol = value.size();
    g.n_cols = ncol;
    g.col.assign(g.width * ncol, 0);
    for (unsigned newest = 0; newest < g.width; ++newest)
        for (std::size_t k = 0; k < ncol; ++k) {
            const std::size_t age = value[k] / nc, ch = value[k] % nc;
            const std::size_t slot = (newest + g.width - age) % g.width;
            g.col[newest * ncol + k] = static_cast<idx>(slot * nc + ch);
        }
}

// x = [y_{k-1}; y_{k-2}; v_{k-1}; v_{k-2}] (p_reg x 1), y = y_k^T (1 x n).
inline double chan(const vibid_regressor &g, long channel, unsigned age) {
    return g.window[g.age_offset[age] + static_cast<std::size_t>(channel)];
}
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
        g->nx = g->p_reg * g->m_eq;
        g->ny = g->m_eq * g->q_out;
        g->n_pad = (g->nx + g->ny + 3) / 4 * 4;
        g->out.assign(g->n_pad, 0.0);
        g->step.n_pad = static_cast<idx>(g->n_pad);
        g->step.linear = !g->zoh;
        if (!g->zoh) compile_structured(*g);
        g->filter_on = prefilter_hz > 0.0;
        if (g->filter_on) {
            design_butterworth4(prefilter_hz, sample_time, g->section);
            g->z.assign(4 * g->n_pad, 0.0);
        }
        // The step's arrays never move after this (push only sets step.col).
        g->step.A = g->A.data();
        g->step.block = g->block.data();
        g->step.window = g->window.data();
        g->step.col = g->col.data();
        g->step.n_cubic = static_cast<idx>(g->cubic.size());
        g->step.cubic = g->cubic.data();
        g->step.sec = g->filter_on ? g->section : nullptr;
        g->step.z = g->z.data();
        g->step.out = g->out.data();
        g->kt = &vibid::kern::active();
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
    vibid_regressor &g = *reg;
    const std::size_t nc = g.n_channels;
    const unsigned slot = g.newest + 1 == g.width ? 0 : g.newest + 1;
    // Copies by plain loops: a few doubles each, where a call to memcpy cost a quarter of
    // the whole push.
    double *const w = g.window.data() + slot * nc;
    for (std::size_t i = 0; i < nc; ++i) w[i] = channels[i];
    g.newest = slot;
    ++g.count;
    if (g.count < g.width) {
        *ready = 0;
        return VIBID_OK;
    }
    if (g.zoh) {
        for (unsigned age = 0, s = slot; age < g.width; ++age, s = s ? s - 1 : g.width - 1)
            g.age_offset[age] = s * nc;
        build_zoh(g, g.out.data(), g.out.data() + g.nx);
    } else {
        g.step.col = g.col.data() + slot * g.n_cols;
    }
    if (!g.zoh || g.filter_on) g.kt->regressor_step(g.step);
    if (g.filter_on) {
        // The constant column through the two biquads (transposed direct form II, as
        // RegStep filters every entry): the filter's step response since the restart.
        double v = 1.0;
        for (int q = 0; q < 2; ++q) {
            const double *c = g.section + 5 * q;
            double *z = g.unit_z + 2 * q;
            const double o = c[0] * v + z[0];
            z[0] = c[1] * v - c[3] * o + z[1];
            z[1] = c[2] * v - c[4] * o;
            v = o;
        }
        g.unit = v;
    }
    const double *const out = g.out.data();
    for (std::size_t i = 0; i < g.nx; ++i) x[i] = out[i];
    for (std::size_t i = 0; i < g.ny; ++i) y[i] = out[g.nx + i];
    *ready = 1;
    return VIBID_OK;
}

}  // extern "C"

double vibid::regressor_unit(const vibid_regressor &reg) { return reg.unit; }
