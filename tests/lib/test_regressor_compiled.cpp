// test_regressor_compiled.cpp: the compiled regressor (lib/src/regressor.cpp: stencils,
// hold equivalents, coefficients and known terms folded into one matrix at create, the
// pre-filter over all entries at once) against the builder it replaced, kept here as the
// reference: a walk over the model's terms and entries per sample, each entry's stencil
// computed from the window, then a scalar biquad cascade per entry. Every x and y entry of
// every sample is compared, for example 1, measured velocities and accelerations, held
// force inputs and a held base, cubic springs (known and unknown), a 10-DOF chain, a
// full-matrix model and the ZOH form, each with difference order 2 and 4 and with and
// without the pre-filter.
//
// Tolerance: |new - reference| <= 1e-12 * scale, with scale the largest |reference| of
// that entry over the run (an entry that is zero throughout must be exactly zero). Both
// compute the same linear combination of the same window values; they differ only in the
// order of the roundings (the compiled form multiplies each value by a folded weight such
// as coef / h^2 and sums; the walk differences first, then divides and multiplies). Each
// rounding is at most an ulp of the largest term, and the largest term here is the
// second-difference term |x| 30 / (12 h^2) of the five-point stencil: with the test's
// signals at 2 kHz (|x| ~ 1e-3 m, |x''| ~ 36 m/s^2, mostly from the 61 Hz component) that
// term is about 300 times the entry's peak, so some ten roundings of 1.1e-16 stay below
// ~3e-13 of the scale (the largest error seen is 8e-14, printed per model). The pre-filter
// passes that on with its gain (about 1). 1e-12 keeps a margin over this bound and over the
// AVX2 path's fused multiply-adds, while any slip of the compilation (a wrong weight,
// sample age, sign or entry) shows as an error of order 1 of the scale.
#include <vibid/model.h>
#include <vibid/regressor.h>

#include "model_internal.hpp"

#include <array>
#include <cmath>
#include <cstdio>
#include <memory>
#include <vector>

extern "C" {
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>
}

namespace {

using vibid::Signal;
using vibid::SignalType;

constexpr double kH = 1.0 / 2000.0;     // s
constexpr double kPrefilterHz = 200.0;  // the daemon's former default
constexpr int kSamples = 3000;
constexpr double kRelTol = 1e-12;       // see the file comment

// ---- the reference: the per-entry builder as it was before compilation ----

struct Ref {
    const vibid_model &model;
    double h;
    std::size_t n, r, nc, p_reg, m_eq, q_out;
    bool zoh;
    unsigned order, width, centre;
    std::vector<double> window;  // ring, slot (count - 1) % width is the newest
    unsigned long long count = 0;
    std::size_t age_offset[5] = {0, 0, 0, 0, 0};
    bool filter_on;
    double sec[2][5];                     // b0 b1 b2 a1 a2
    std::vector<std::array<double, 4>> z; // per entry: two delays per biquad

    Ref(const vibid_model &m, double sample_time, double prefilter_hz, unsigned difference_order)
        : model(m), h(sample_time), n(m.nodes.size()), r(m.inputs.size()), nc(m.channels.size()),
          zoh(m.discretization == VIBID_DISC_ZOH) {
        if (zoh) {
            const std::size_t rz = r + (m.has_base ? 1 : 0);
            p_reg = 2 * n + 2 * rz;
            m_eq = 1;
            q_out = n;
        } else {
            p_reg = m.param_term.size();
            m_eq = n;
            q_out = 1;
        }
        order = zoh ? 2 : difference_order;
        width = order + 1;
        centre = order / 2;
        window.assign(width * nc, 0.0);
        filter_on = prefilter_hz > 0.0;
        z.assign(p_reg * m_eq + m_eq * q_out, {0.0, 0.0, 0.0, 0.0});
        if (filter_on) design(prefilter_hz);
    }

    // 4th-order Butterworth as two low-pass biquads, bilinear transform with pre-warping
    // (K = tan(w0 / 2)): the textbook form, not the library's (RBJ) algebra, so that the
    // design is checked too (both agree to rounding).
    void design(double fc) {
        const double K = std::tan(M_PI * fc * h);
        const double Q[2] = {1.0 / (2.0 * std::cos(M_PI / 8.0)), 1.0 / (2.0 * std::cos(3.0 * M_PI / 8.0))};
        for (int i = 0; i < 2; ++i) {
            const double norm = 1.0 / (1.0 + K / Q[i] + K * K);
            sec[i][0] = K * K * norm;
            sec[i][1] = 2.0 * sec[i][0];
            sec[i][2] = sec[i][0];
            sec[i][3] = 2.0 * (K * K - 1.0) * norm;
            sec[i][4] = (1.0 - K / Q[i] + K * K) * norm;
        }
    }

    double filter(std::array<double, 4> &st, double x) const {
        double v = x;
        for (int i = 0; i < 2; ++i) {
            const double o = sec[i][0] * v + st[2 * i];
            st[2 * i] = sec[i][1] * v - sec[i][3] * o + st[2 * i + 1];
            st[2 * i + 1] = sec[i][2] * v - sec[i][4] * o;
            v = o;
        }
        return v;
    }

    double chan(long channel, unsigned age) const { return window[age_offset[age] + static_cast<std::size_t>(channel)]; }
    double at(long channel, int j) const { return chan(channel, static_cast<unsigned>(static_cast<int>(centre) - j)); }
    double first_derivative(long c) const {
        if (order == 2) return (at(c, 1) - at(c, -1)) / (2.0 * h);
        return (at(c, -2) - 8.0 * at(c, -1) + 8.0 * at(c, 1) - at(c, 2)) / (12.0 * h);
    }
    double second_derivative(long c) const {
        if (order == 2) return (at(c, 1) - 2.0 * at(c, 0) + at(c, -1)) / (h * h);
        return (-at(c, 2) + 16.0 * at(c, 1) - 30.0 * at(c, 0) + 16.0 * at(c, -1) - at(c, -2)) / (12.0 * h * h);
    }
    double held_value(long c) const {
        if (order == 2) return 0.5 * (at(c, -1) + at(c, 0));
        return (13.0 * (at(c, -1) + at(c, 0)) - (at(c, -2) + at(c, 1))) / 24.0;
    }
    double held_derivative(long c) const { return (at(c, 0) - at(c, -1)) / h; }
    double centre_quantity(std::size_t node, int q) const {
        if (node == VIBID_GROUND) return 0.0;
        const std::array<long, 3> &ch = node == VIBID_BASE ? model.base_channel : model.node_channel[node];
        if (node == VIBID_BASE && model.base_hold == VIBID_HOLD_ZOH && q < 2 && ch[0] != vibid::kNoChannel)
            return q == 0 ? held_value(ch[0]) : held_derivative(ch[0]);
        if (ch[q] != vibid::kNoChannel) return at(ch[q], 0);
        if (q == 1) return first_derivative(ch[0]);
        if (ch[1] != vibid::kNoChannel) return first_derivative(ch[1]);
        return second_derivative(ch[0]);
    }
    double input_value(std::size_t j, std::size_t row) const {
        const long c = model.input_channel[j];
        if (model.inputs[j].hold != VIBID_HOLD_ZOH) return at(c, 0);
        if (row < n && model.node_channel[row][2] != vibid::kNoChannel) return at(c, 0);
        return held_value(c);
    }

    void build_structured(double *x, double *y) const {
        const std::size_t p = p_reg;
        for (std::size_t i = 0; i < p * m_eq; ++i) x[i] = 0.0;
        for (std::size_t i = 0; i < m_eq; ++i) y[i] = 0.0;
        for (const auto &t : model.terms) {
            for (const auto &e : t.entries) {
                const Signal &s = e.signal;
                double val = 0.0;
                switch (s.type) {
                case SignalType::Input: val = input_value(s.a, e.row); break;
                case SignalType::Displacement: val = centre_quantity(s.a, 0) - centre_quantity(s.b, 0); break;
                case SignalType::Velocity: val = centre_quantity(s.a, 1) - centre_quantity(s.b, 1); break;
                case SignalType::Acceleration: val = centre_quantity(s.a, 2) - centre_quantity(s.b, 2); break;
                case SignalType::Cubic: {
                    const double rel = centre_quantity(s.a, 0) - centre_quantity(s.b, 0);
                    val = rel * rel * rel;
                    break;
                }
                }
                if (t.unknown)
                    x[static_cast<std::size_t>(t.param) + e.row * p] += e.coef * val;
                else
                    y[e.row] -= t.value * e.coef * val;
            }
        }
    }

    void build_zoh(double *x, double *y) const {
        const std::size_t rz = (p_reg - 2 * n) / 2;
        for (std::size_t i = 0; i < n; ++i) {
            const long c = model.node_channel[i][0];
            y[i] = chan(c, 0);
            x[i] = chan(c, 1);
            x[n + i] = chan(c, 2);
        }
        for (std::size_t j = 0; j < rz; ++j) {
            const long c = j < r ? model.input_channel[j] : model.base_channel[0];
            x[2 * n + j] = chan(c, 1);
            x[2 * n + rz + j] = chan(c, 2);
        }
    }

    bool push(const double *channels, double *x, double *y) {
        const std::size_t slot = static_cast<std::size_t>(count % width);
        for (std::size_t i = 0; i < nc; ++i) window[slot * nc + i] = channels[i];
        ++count;
        if (count < width) return false;
        for (unsigned age = 0, s = static_cast<unsigned>(slot); age < width; ++age, s = s ? s - 1 : width - 1)
            age_offset[age] = s * nc;
        if (zoh)
            build_zoh(x, y);
        else
            build_structured(x, y);
        if (filter_on) {
            const std::size_t nx = p_reg * m_eq, ny = m_eq * q_out;
            for (std::size_t i = 0; i < nx; ++i) x[i] = filter(z[i], x[i]);
            for (std::size_t i = 0; i < ny; ++i) y[i] = filter(z[nx + i], y[i]);
        }
        return true;
    }
};

// ---- models ----

struct Built {
    vibid_model *m;
    const char *name;
};

vibid_model *finish(vibid_model *m) {
    assert_int_equal(vibid_model_finalize(m), VIBID_OK);
    return m;
}

// Paper example 1 (examples/stands/paper_example1.cfg): base excitation, displacements only.
vibid_model *example1(bool cubic, bool held_base, bool known_cubic) {
    vibid_model *m = vibid_model_create();
    assert_non_null(m);
    std::size_t a = 0, b = 0;
    assert_int_equal(vibid_model_add_node(m, "m1", 10.0, 0, &a), VIBID_OK);
    assert_int_equal(vibid_model_add_node(m, "m2", 20.0, 0, &b), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "c1", VIBID_ELEMENT_SPRING, a, b, 2.5e5, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "d", VIBID_ELEMENT_DAMPER, a, b, 300.0, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "c2", VIBID_ELEMENT_SPRING, b, VIBID_BASE, 1.5e6, 1), VIBID_OK);
    // Paper example 2 (examples/stands/paper_example2.cfg): the cubic spring m2-base.
    if (cubic)
        assert_int_equal(
            vibid_model_add_element(m, "eps", VIBID_ELEMENT_CUBIC_SPRING, b, VIBID_BASE, 2e9, known_cubic ? 0 : 1),
            VIBID_OK);
    if (held_base) {
        // A damper to a held base: the hold's derivative (an impulse per jump) reaches m1.
        assert_int_equal(vibid_model_add_element(m, "d0", VIBID_ELEMENT_DAMPER, a, VIBID_BASE, 40.0, 1), VIBID_OK);
        assert_int_equal(vibid_model_set_hold(m, VIBID_BASE, VIBID_HOLD_ZOH), VIBID_OK);
    }
    assert_int_equal(vibid_model_set_measured(m, a, VIBID_MEASURE_DISPLACEMENT), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m, b, VIBID_MEASURE_DISPLACEMENT), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m, VIBID_BASE, VIBID_MEASURE_DISPLACEMENT), VIBID_OK);
    return finish(m);
}

// Three masses on the ground with every way of getting a derivative: m1 displacement and
// acceleration (measured, used directly), m2 displacement and velocity (acceleration
// differenced from the velocity), m3 displacement only (both differenced); an unknown
// mass, known and unknown springs and dampers (known ones go into y), force inputs with a
// known and an unknown gain, held (ZOH) or smooth. The held input on m1 enters as sampled
// (m1's accelerometer), the one on m3 by its hold equivalent.
vibid_model *chain(bool held_inputs, vibid_discretization disc) {
    vibid_model *m = vibid_model_create();
    assert_non_null(m);
    std::size_t n[3] = {0, 0, 0};
    assert_int_equal(vibid_model_add_node(m, "m1", 1.0, 0, &n[0]), VIBID_OK);
    assert_int_equal(vibid_model_add_node(m, "m2", 1.5, disc == VIBID_DISC_ZOH ? 0 : 1, &n[1]), VIBID_OK);
    assert_int_equal(vibid_model_add_node(m, "m3", 2.0, 0, &n[2]), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "k1", VIBID_ELEMENT_SPRING, n[0], VIBID_GROUND, 4e4, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "d1", VIBID_ELEMENT_DAMPER, n[0], VIBID_GROUND, 20.0, 0), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "k2", VIBID_ELEMENT_SPRING, n[1], n[0], 3e4, 0), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "d2", VIBID_ELEMENT_DAMPER, n[1], n[0], 15.0, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "k3", VIBID_ELEMENT_SPRING, n[2], n[1], 2e4, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "d3", VIBID_ELEMENT_DAMPER, n[2], n[1], 10.0, 1), VIBID_OK);
    std::size_t f1 = 0, f3 = 0;
    assert_int_equal(vibid_model_add_input(m, "f1", n[0], 2.0, 0, &f1), VIBID_OK);
    assert_int_equal(vibid_model_add_input(m, "f3", n[2], 1.0, disc == VIBID_DISC_ZOH ? 0 : 1, &f3), VIBID_OK);
    if (held_inputs) {
        assert_int_equal(vibid_model_set_hold(m, f1, VIBID_HOLD_ZOH), VIBID_OK);
        assert_int_equal(vibid_model_set_hold(m, f3, VIBID_HOLD_ZOH), VIBID_OK);
    }
    const unsigned d = VIBID_MEASURE_DISPLACEMENT;
    const bool zoh = disc == VIBID_DISC_ZOH;
    assert_int_equal(vibid_model_set_measured(m, n[0], zoh ? d : d | VIBID_MEASURE_ACCELERATION), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m, n[1], zoh ? d : d | VIBID_MEASURE_VELOCITY), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m, n[2], d), VIBID_OK);
    assert_int_equal(vibid_model_set_discretization(m, disc), VIBID_OK);
    return finish(m);
}

// Ten masses in a row from the moving base, every spring and damper unknown, velocities
// measured on every other mass, a held force on the last: 20 unknowns, 10 equations, 53
// blocks of the compiled form (a model where most window values are not read by most
// entries).
vibid_model *long_chain() {
    vibid_model *m = vibid_model_create();
    assert_non_null(m);
    std::size_t prev = VIBID_BASE, node = 0;
    for (int i = 0; i < 10; ++i) {
        char name[16]; /* "m" and any int: no truncation warning at any -O */
        std::snprintf(name, sizeof name, "m%d", i);
        assert_int_equal(vibid_model_add_node(m, name, 1.0 + 0.1 * i, 0, &node), VIBID_OK);
        std::snprintf(name, sizeof name, "k%d", i);
        assert_int_equal(vibid_model_add_element(m, name, VIBID_ELEMENT_SPRING, node, prev, 1e4 * (1 + i), 1), VIBID_OK);
        std::snprintf(name, sizeof name, "d%d", i);
        assert_int_equal(vibid_model_add_element(m, name, VIBID_ELEMENT_DAMPER, node, prev, 5.0 + i, 1), VIBID_OK);
        const unsigned meas = VIBID_MEASURE_DISPLACEMENT | (i % 2 ? VIBID_MEASURE_VELOCITY : 0u);
        assert_int_equal(vibid_model_set_measured(m, node, meas), VIBID_OK);
        prev = node;
    }
    std::size_t f = 0;
    assert_int_equal(vibid_model_add_input(m, "f", node, 1.0, 0, &f), VIBID_OK);
    assert_int_equal(vibid_model_set_hold(m, f, VIBID_HOLD_ZOH), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m, VIBID_BASE, VIBID_MEASURE_DISPLACEMENT), VIBID_OK);
    return finish(m);
}

// Full matrices (1.4): M known, D and C unknown (upper triangles), B known.
vibid_model *full_matrix() {
    vibid_model *m = vibid_model_create();
    assert_non_null(m);
    const double M[4] = {2.0, 0.0, 0.0, 3.0}, D[4] = {5.0, -2.0, -2.0, 4.0}, C[4] = {3e4, -1e4, -1e4, 2e4},
                 B[2] = {1.0, 0.5};
    assert_int_equal(vibid_model_set_matrices(m, 2, 1, M, D, C, B, 2u | 4u), VIBID_OK);
    return finish(m);
}

// Channel c's signal at sample k: three sines (7, 23, 61 Hz) at amplitudes whose
// displacement is ~1e-3 (scaled by w^q for a derivative of order q, input channels ~10),
// plus a little white noise, so that every stencil sees both smooth motion and
// sample-to-sample jumps.
double signal(const vibid_channel_info &ci, std::size_t c, int k, unsigned &seed) {
    static const double f[3] = {7.0, 23.0, 61.0}, amp[3] = {0.5e-3, 0.3e-3, 0.2e-3};
    const int q = ci.kind == VIBID_CHANNEL_VELOCITY ? 1 : ci.kind == VIBID_CHANNEL_ACCELERATION ? 2 : 0;
    const double scale = ci.kind == VIBID_CHANNEL_INPUT ? 1e4 : 1.0;
    double v = 0.0;
    for (int i = 0; i < 3; ++i) {
        const double w = 2.0 * M_PI * f[i];
        v += scale * amp[i] * std::pow(w, q) * std::sin(w * k * kH + 0.7 * static_cast<double>(c + i));
    }
    seed = seed * 1103515245u + 12345u;
    const double u = static_cast<double>((seed >> 8) & 0xffff) / 65536.0 - 0.5;
    return v * (1.0 + 1e-3 * u);
}

// Runs the compiled regressor and the reference side by side over kSamples samples and
// checks every entry (see the file comment for the tolerance). Returns the largest error
// relative to its entry's scale, for the report. At sample gap_at (if >= 0) a sample with a
// NaN is pushed first, which must be refused with `ready` untouched and change nothing; at
// sample reset_at (if >= 0) the regressor is reset and the reference started afresh.
double compare(const vibid_model *m, const char *what, double prefilter_hz, unsigned order, int gap_at = -1,
               int reset_at = -1) {
    vibid_regressor *reg = vibid_regressor_create_order(m, kH, prefilter_hz, order);
    if (!reg) {
        std::printf("%s: %s\n", what, vibid_last_error());
        fail();
    }
    vibid_regressor_dims dims{};
    assert_int_equal(vibid_regressor_get_dims(reg, &dims), VIBID_OK);
    auto ref = std::make_unique<Ref>(*m, kH, prefilter_hz, order);
    const std::size_t nx = dims.n_regressors * dims.n_equations, ny = dims.n_equations * dims.n_outputs;
    assert_int_equal(nx, ref->p_reg * ref->m_eq);
    assert_int_equal(ny, ref->m_eq * ref->q_out);
    const unsigned width = ref->width;
    const std::size_t nc = m->channels.size(), ne = nx + ny;
    std::vector<vibid_channel_info> info(nc);
    for (std::size_t c = 0; c < nc; ++c) assert_int_equal(vibid_model_channel_info(m, c, &info[c]), VIBID_OK);

    // All samples first: the scale of an entry is its peak over the whole run.
    std::vector<double> got, want;
    std::vector<double> ch(nc), x(nx), y(ny), xr(nx), yr(ny);
    unsigned seed = 12345u;
    int rows = 0;
    for (int k = 0; k < kSamples; ++k) {
        for (std::size_t c = 0; c < nc; ++c) ch[c] = signal(info[c], c, k, seed);
        int ready = -1;
        if (k == gap_at) {
            std::vector<double> bad = ch;
            bad[nc - 1] = NAN;
            assert_int_equal(vibid_regressor_push(reg, bad.data(), x.data(), y.data(), &ready), VIBID_E_NONFINITE);
            assert_int_equal(ready, -1);
        }
        if (k == reset_at) {
            assert_int_equal(vibid_regressor_reset(reg), VIBID_OK);
            ref = std::make_unique<Ref>(*m, kH, prefilter_hz, order);
        }
        assert_int_equal(vibid_regressor_push(reg, ch.data(), x.data(), y.data(), &ready), VIBID_OK);
        const bool ref_ready = ref->push(ch.data(), xr.data(), yr.data());
        assert_int_equal(ready, ref_ready ? 1 : 0);
        if (!ready) continue;
        ++rows;
        got.insert(got.end(), x.begin(), x.end());
        got.insert(got.end(), y.begin(), y.end());
        want.insert(want.end(), xr.begin(), xr.end());
        want.insert(want.end(), yr.begin(), yr.end());
    }
    assert_int_equal(rows, kSamples - static_cast<int>(width - 1) * (reset_at >= 0 ? 2 : 1));
    double worst = 0.0;
    for (std::size_t e = 0; e < ne; ++e) {
        double scale = 0.0;
        for (int k = 0; k < rows; ++k) scale = std::fmax(scale, std::fabs(want[k * ne + e]));
        for (int k = 0; k < rows; ++k) {
            const double err = std::fabs(got[k * ne + e] - want[k * ne + e]);
            if (!(err <= kRelTol * scale)) {
                std::printf("%s (order %u, pre-filter %g Hz): entry %zu (%s) at row %d: %.17g, reference %.17g "
                            "(scale %g, tolerance %g)\n",
                            what, order, prefilter_hz, e < nx ? e : e - nx, e < nx ? "x" : "y", k,
                            got[k * ne + e], want[k * ne + e], scale, kRelTol * scale);
                fail();
            }
            if (scale > 0.0) worst = std::fmax(worst, err / scale);
        }
    }
    vibid_regressor_destroy(reg);
    return worst;
}

// Compares model m (destroyed here) for both orders, with and without the pre-filter.
void run_all(vibid_model *m, const char *what) {
    double worst = 0.0;
    for (unsigned order : {2u, 4u})
        for (double fc : {0.0, kPrefilterHz}) worst = std::fmax(worst, compare(m, what, fc, order));
    std::printf("  %-44s largest error %.2g of the entry's scale (tolerance %g)\n", what, worst, kRelTol);
    vibid_model_destroy(m);
}

void test_example1(void **) { run_all(example1(false, false, false), "example 1 (base excitation)"); }

void test_example2_cubic(void **) {
    run_all(example1(true, false, false), "example 2 (cubic spring, unknown)");
    run_all(example1(true, false, true), "example 2 (cubic spring, known: into y)");
}

// Cubic and damper to a held base: multi-tap hold equivalents in a cube and a rate.
void test_held_base(void **) { run_all(example1(true, true, false), "held base, damper and cubic spring to it"); }

void test_measured_derivatives_and_inputs(void **) {
    run_all(chain(false, VIBID_DISC_CENTRAL_DIFFERENCE), "chain, measured vel/acc, smooth inputs");
    run_all(chain(true, VIBID_DISC_CENTRAL_DIFFERENCE), "chain, measured vel/acc, held inputs");
}

void test_full_matrix(void **) { run_all(full_matrix(), "full matrices, D and C unknown"); }

void test_long_chain(void **) { run_all(long_chain(), "10-DOF chain on the base, held force"); }

// The ZOH form (1.16) is a copy of window values: only the pre-filter is new there.
void test_zoh_form(void **) { run_all(chain(true, VIBID_DISC_ZOH), "ZOH form (1.16), held inputs"); }

// A NaN sample is refused without touching the builder (window, ring position, filter
// delays): the rows after it still match the reference, which never saw it. A reset
// restarts the window and the filter: the rows after it match a fresh reference.
void test_gap_and_reset(void **) {
    vibid_model *m = example1(true, false, false);
    for (unsigned order : {2u, 4u}) {
        const double worst = compare(m, "gap and reset", kPrefilterHz, order, 1000, 2000);
        std::printf("  gap and reset, order %u: largest error %.2g of the entry's scale\n", order, worst);
    }
    vibid_model_destroy(m);
}

}  // namespace

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_example1),
        cmocka_unit_test(test_example2_cubic),
        cmocka_unit_test(test_held_base),
        cmocka_unit_test(test_measured_derivatives_and_inputs),
        cmocka_unit_test(test_full_matrix),
        cmocka_unit_test(test_long_chain),
        cmocka_unit_test(test_zoh_form),
        cmocka_unit_test(test_gap_and_reset),
    };
    return cmocka_run_group_tests(tests, nullptr, nullptr);
}
