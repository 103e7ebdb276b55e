// model.cpp: the lumped-network / full-matrix model description, its structured form
// (4.1), the identifiability checks (ref. [7]) and the force evaluation for simulation.
#include <vibid/model.h>

#include "api_guard.hpp"
#include "model_internal.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <complex>
#include <cstring>
#include <string>

using vibid::Entry;
using vibid::Signal;
using vibid::SignalType;
using vibid::Term;
using vibid::throw_error;

namespace {

const char *kind_name(vibid_element_kind kind) {
    switch (kind) {
    case VIBID_ELEMENT_SPRING: return "spring";
    case VIBID_ELEMENT_DAMPER: return "damper";
    case VIBID_ELEMENT_CUBIC_SPRING: return "cubic spring";
    }
    return "element";
}

void require_model(const vibid_model *model) {
    if (!model) throw_error(VIBID_E_NULL_ARGUMENT, "model is NULL");
}

void require_editable(const vibid_model *model) {
    require_model(model);
    if (model->frozen) throw_error(VIBID_E_STATE, "model is finalized; reset it to change the description");
}

// Names are used as channel names and in messages, and the loader looks them up: keep
// them short and printable; "ground" and "base" are the pseudo nodes.
void check_name(const vibid_model *model, const char *name, const char *what) {
    if (!name) throw_error(VIBID_E_NULL_ARGUMENT, "%s name is NULL", what);
    std::size_t len = std::strlen(name);
    if (len == 0 || len > 63) throw_error(VIBID_E_OUT_OF_RANGE, "%s name '%.63s' must have 1..63 characters", what, name);
    for (std::size_t i = 0; i < len; ++i)
        if (name[i] <= ' ' || name[i] > '~')
            throw_error(VIBID_E_OUT_OF_RANGE, "%s name '%s' contains a space or non-printable character", what, name);
    if (!std::strcmp(name, "ground") || !std::strcmp(name, "base"))
        throw_error(VIBID_E_OUT_OF_RANGE, "%s name '%s' is reserved", what, name);
    const auto it = model->names.find(name);
    if (it != model->names.end()) {
        const char k = it->second.first;
        throw_error(VIBID_E_OUT_OF_RANGE, "%s name '%s' is already used by %s", what, name,
                    k == 'n' ? "a node" : k == 'e' ? "an element" : k == 'i' ? "an input" : "a disturbance");
    }
}

// Appends item (a Node, Element, Input or Disturbance) to list and its name to the model's
// index of names (kind as there); both or neither.
template <class List, class Item>
void add_named(vibid_model *model, List &list, Item &&item, char kind) {
    const auto ins = model->names.emplace(item.name, std::make_pair(kind, list.size()));
    try {
        list.push_back(std::forward<Item>(item));
    } catch (...) {
        model->names.erase(ins.first);
        throw;
    }
}

// Index 0..2 of a single VIBID_MEASURE_* bit; throws otherwise.
int quantity_index(unsigned quantity) {
    switch (quantity) {
    case VIBID_MEASURE_DISPLACEMENT: return 0;
    case VIBID_MEASURE_VELOCITY: return 1;
    case VIBID_MEASURE_ACCELERATION: return 2;
    }
    throw_error(VIBID_E_OUT_OF_RANGE, "quantity 0x%x is not one VIBID_MEASURE_* bit", quantity);
}

const char *end_name(const vibid_model &m, std::size_t node) {
    if (node == VIBID_GROUND) return "ground";
    if (node == VIBID_BASE) return "base";
    return m.nodes[node].name.c_str();
}

// Builds terms and channels from the description (finalize).
void derive_structure(vibid_model &m) {
    m.terms.clear();
    m.param_term.clear();
    m.channels.clear();
    m.node_channel.assign(m.nodes.size(), {{vibid::kNoChannel, vibid::kNoChannel, vibid::kNoChannel}});
    m.input_channel.assign(m.inputs.size(), vibid::kNoChannel);
    m.base_channel = {{vibid::kNoChannel, vibid::kNoChannel, vibid::kNoChannel}};
    m.has_base = false;
    m.base_damper = false;
    m.nonlinear = false;

    if (m.full_matrix) {
        m.terms = m.matrix_terms;
    } else {
        for (std::size_t i = 0; i < m.nodes.size(); ++i) {
            const auto &n = m.nodes[i];
            Term t{n.name, VIBID_PARAM_MASS, n.mass, n.unknown, -1, {}};
            t.entries.push_back(Entry{i, 1.0, Signal{SignalType::Acceleration, i, VIBID_GROUND}});
            m.terms.push_back(std::move(t));
        }
        for (const auto &e : m.elements) {
            SignalType st = SignalType::Displacement;
            vibid_param_kind pk = VIBID_PARAM_STIFFNESS;
            if (e.kind == VIBID_ELEMENT_DAMPER) {
                st = SignalType::Velocity;
                pk = VIBID_PARAM_DAMPING;
            } else if (e.kind == VIBID_ELEMENT_CUBIC_SPRING) {
                st = SignalType::Cubic;
                pk = VIBID_PARAM_CUBIC;
                m.nonlinear = true;
            }
            Term t{e.name, pk, e.value, e.unknown, -1, {}};
            Signal s{st, e.a, e.b};
            t.entries.push_back(Entry{e.a, 1.0, s});
            if (e.b < m.nodes.size()) t.entries.push_back(Entry{e.b, -1.0, s});
            if (e.b == VIBID_BASE) {
                m.has_base = true;
                if (e.kind != VIBID_ELEMENT_SPRING) m.base_damper = true;
            }
            m.terms.push_back(std::move(t));
        }
        for (std::size_t j = 0; j < m.inputs.size(); ++j) {
            const auto &u = m.inputs[j];
            Term t{u.name, VIBID_PARAM_GAIN, u.gain, u.unknown, -1, {}};
            t.entries.push_back(Entry{u.node, -1.0, Signal{SignalType::Input, j, 0}});
            m.terms.push_back(std::move(t));
        }
    }
    for (std::size_t k = 0; k < m.terms.size(); ++k) {
        if (m.terms[k].unknown) {
            m.terms[k].param = static_cast<long>(m.param_term.size());
            m.param_term.push_back(k);
        } else {
            m.terms[k].param = -1;
        }
    }

    static const char *const qname[3] = {"displacement", "velocity", "acceleration"};
    static const vibid_channel_kind qkind[3] = {VIBID_CHANNEL_DISPLACEMENT, VIBID_CHANNEL_VELOCITY,
                                                VIBID_CHANNEL_ACCELERATION};
    for (std::size_t i = 0; i < m.nodes.size(); ++i)
        for (int q = 0; q < 3; ++q)
            if (m.nodes[i].measured & (1u << q)) {
                m.node_channel[i][q] = static_cast<long>(m.channels.size());
                m.channels.push_back(vibid::Channel{m.nodes[i].name + "." + qname[q], qkind[q], i});
            }
    for (int q = 0; q < 3; ++q)
        if (m.base_measured & (1u << q)) {
            m.base_channel[q] = static_cast<long>(m.channels.size());
            m.channels.push_back(vibid::Channel{std::string("base.") + qname[q], qkind[q], VIBID_BASE});
        }
    for (std::size_t j = 0; j < m.inputs.size(); ++j) {
        m.input_channel[j] = static_cast<long>(m.channels.size());
        m.channels.push_back(vibid::Channel{m.inputs[j].name, VIBID_CHANNEL_INPUT, j});
    }
}

using MatX = Eigen::MatrixXd;
using VecX = Eigen::VectorXd;

struct Assembled {
    MatX M, D, C, B;
    VecX d_base, c_base;
};

// Linear part of the equation at theta; with only_param >= 0 the derivative with respect
// to that unknown (the structure matrix of (4.1)), into the caller's column-major arrays
// (M, D, C n x n, B n x r, d_base, c_base n; any may be NULL: not written). Allocates
// nothing (vibid_model_assemble runs on a reported row's path: modal_work.hpp).
void assemble_into(const vibid_model &m, const double *theta, long only_param, double *M, double *D, double *C,
                   double *B, double *d_base, double *c_base) {
    const std::size_t n = m.nodes.size(), r = m.inputs.size();
    for (double *x : {M, D, C})
        if (x) std::fill(x, x + n * n, 0.0);
    if (B) std::fill(B, B + n * r, 0.0);
    for (double *x : {d_base, c_base})
        if (x) std::fill(x, x + n, 0.0);
    for (const auto &t : m.terms) {
        double v;
        if (only_param >= 0)
            v = (t.param == only_param) ? 1.0 : 0.0;
        else
            v = vibid::term_value(t, theta);
        if (v == 0.0) continue;
        for (const auto &e : t.entries) {
            const double cv = e.coef * v;
            const Signal &s = e.signal;
            double *target = nullptr, *base = nullptr;
            switch (s.type) {
            case SignalType::Acceleration: target = M; break;
            case SignalType::Velocity: target = D; base = d_base; break;
            case SignalType::Displacement: target = C; base = c_base; break;
            case SignalType::Cubic: continue;  // nonlinear: not part of the linear matrices
            case SignalType::Input:
                if (B) B[e.row + s.a * n] -= cv;
                continue;
            }
            if (target) target[e.row + s.a * n] += cv;
            if (s.b < n) {
                if (target) target[e.row + s.b * n] -= cv;
            } else if (s.b == VIBID_BASE && base) {
                base[e.row] += cv;  // coef v (y_a - s): the s part moves to the right-hand side
            }
        }
    }
}

Assembled assemble(const vibid_model &m, const double *theta, long only_param) {
    const std::size_t n = m.nodes.size(), r = m.inputs.size();
    Assembled a{MatX(n, n), MatX(n, n), MatX(n, n), MatX(n, r), VecX(n), VecX(n)};
    assemble_into(m, theta, only_param, a.M.data(), a.D.data(), a.C.data(), a.B.data(), a.d_base.data(),
                  a.c_base.data());
    return a;
}

bool regular(const MatX &A) {
    if (A.rows() != A.cols() || A.rows() == 0) return false;
    Eigen::JacobiSVD<MatX> svd(A);
    const auto &s = svd.singularValues();
    return s(s.size() - 1) > 1e-12 * s(0) && s(0) > 0.0;
}

// Lists the names of the parameters with large components in a null-space vector.
std::string null_space_names(const vibid_model &m, const VecX &v) {
    std::string out;
    const double vmax = v.cwiseAbs().maxCoeff();
    for (Eigen::Index i = 0; i < v.size(); ++i)
        if (std::fabs(v(i)) > 0.1 * vmax) {
            if (!out.empty()) out += ", ";
            out += m.terms[m.param_term[static_cast<std::size_t>(i)]].name;
        }
    return out;
}

// Generic (structural) regressor: the structured regressor evaluated with independent
// pseudo-random values for every signal, many samples. Full column rank here means no
// two combinations of unknowns have the same structure; a rank loss is structural and
// no data can cure it.
void check_generic_rank(const vibid_model &m, vibid_identifiability &rep) {
    const std::size_t n = m.nodes.size(), p = m.param_term.size(), r = m.inputs.size();
    const std::size_t n_samples = 3 * p + 8;
    MatX X = MatX::Zero(n_samples * n, p);
    // Deterministic generator: reproducible messages, no global state.
    std::uint64_t state = 0x9e3779b97f4a7c15ull;
    auto next = [&state]() {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        return static_cast<double>(state >> 11) * (1.0 / 9007199254740992.0) * 2.0 - 1.0;
    };
    std::vector<double> y(3 * n), s(3), u(r);
    for (std::size_t k = 0; k < n_samples; ++k) {
        for (auto &v : y) v = next();
        for (auto &v : s) v = next();
        for (auto &v : u) v = next();
        for (const auto &t : m.terms) {
            if (!t.unknown) continue;
            for (const auto &e : t.entries) {
                const Signal &sg = e.signal;
                double val;
                if (sg.type == SignalType::Input) {
                    val = u[sg.a];
                } else {
                    int q = sg.type == SignalType::Velocity ? 1 : sg.type == SignalType::Acceleration ? 2 : 0;
                    double rb = sg.b < n ? y[3 * sg.b + q] : sg.b == VIBID_BASE ? s[q] : 0.0;
                    val = y[3 * sg.a + q] - rb;
                    if (sg.type == SignalType::Cubic) val = val * val * val;
                }
                X(static_cast<Eigen::Index>(k * n + e.row), t.param) += e.coef * val;
            }
        }
    }
    for (Eigen::Index j = 0; j < X.cols(); ++j) {
        double nrm = X.col(j).norm();
        if (nrm > 0) X.col(j) /= nrm;
    }
    Eigen::JacobiSVD<MatX> svd(X, Eigen::ComputeFullV);
    const auto &sv = svd.singularValues();
    std::size_t rank = 0;
    for (Eigen::Index i = 0; i < sv.size(); ++i)
        if (sv(i) > 1e-9 * std::max(sv(0), 1e-300)) ++rank;
    rep.generic_rank = rank;
    if (rank < p) {
        std::string names;
        for (std::size_t i = rank; i < p; ++i) {
            if (!names.empty()) names += "; ";
            names += "{" + null_space_names(m, svd.matrixV().col(static_cast<Eigen::Index>(i))) + "}";
        }
        throw_error(VIBID_E_NOT_IDENTIFIABLE,
                    "the structure cannot separate these parameters (same regressor up to a combination): %s; make "
                    "one of them known",
                    names.c_str());
    }
}

// Value used for an unknown in the controllability check: its nominal value, or a
// generic value of the right scale when none was given.
double nominal_or_generic(const Term &t, const vibid_model &m) {
    if (t.value != 0.0) return t.value;
    // Scale from the known terms of the same kind, else 1.
    for (const auto &o : m.terms)
        if (!o.unknown && o.kind == t.kind && o.value != 0.0) return std::fabs(o.value) * 1.37;
    return 1.0;
}

// PBH test: (A, Bin) controllable iff rank [A - lambda I, Bin] = 2n for every eigenvalue
// lambda of A. Names the nodes that move in an uncontrollable mode.
void check_controllable(const vibid_model &m, vibid_identifiability &rep, bool strict) {
    const std::size_t n = m.nodes.size();
    std::vector<double> theta(m.param_term.size());
    for (std::size_t i = 0; i < theta.size(); ++i) theta[i] = nominal_or_generic(m.terms[m.param_term[i]], m);
    Assembled a = assemble(m, theta.data(), -1);
    if (!regular(a.M)) {
        rep.controllable = 0;
        if (strict) throw_error(VIBID_E_NOT_IDENTIFIABLE, "mass matrix is singular at the nominal values");
        return;
    }
    Eigen::PartialPivLU<MatX> lu(a.M);
    const Eigen::Index N = static_cast<Eigen::Index>(n);
    MatX A = MatX::Zero(2 * N, 2 * N);
    A.topRightCorner(N, N).setIdentity();
    A.bottomLeftCorner(N, N) = -lu.solve(a.C);
    A.bottomRightCorner(N, N) = -lu.solve(a.D);
    MatX Bf(N, a.B.cols() + 2);
    Bf << a.B, a.c_base, a.d_base;
    MatX Bin = MatX::Zero(2 * N, Bf.cols());
    Bin.bottomRows(N) = lu.solve(Bf);
    if (Bin.cwiseAbs().maxCoeff() == 0.0) {
        rep.controllable = 0;
        throw_error(VIBID_E_NOT_IDENTIFIABLE,
                    "no excitation: the model has no force input and no element to the base, so nothing excites it");
    }
    Eigen::EigenSolver<MatX> es(A);
    if (es.info() != Eigen::Success) throw_error(VIBID_E_NUMERICAL, "eigen solver failed in the controllability check");
    const double scale = std::max(A.norm(), 1e-300);
    const Eigen::MatrixXcd Bc = Bin.cast<std::complex<double>>();
    for (Eigen::Index i = 0; i < 2 * N; ++i) {
        const std::complex<double> lambda = es.eigenvalues()(i);
        Eigen::MatrixXcd P(2 * N, 2 * N + Bin.cols());
        P << A.cast<std::complex<double>>() - lambda * Eigen::MatrixXcd::Identity(2 * N, 2 * N),
            Bc * (scale / std::max(Bin.norm(), 1e-300));
        Eigen::JacobiSVD<Eigen::MatrixXcd> svd(P);
        const auto &sv = svd.singularValues();
        if (sv(2 * N - 1) <= 1e-9 * sv(0)) {
            rep.controllable = 0;
            const Eigen::VectorXcd v = es.eigenvectors().col(i).head(N);
            const double vmax = v.cwiseAbs().maxCoeff();
            std::string names;
            for (Eigen::Index k = 0; k < N; ++k)
                if (std::abs(v(k)) > 0.1 * vmax) {
                    if (!names.empty()) names += ", ";
                    names += m.nodes[static_cast<std::size_t>(k)].name;
                }
            throw_error(VIBID_E_NOT_IDENTIFIABLE,
                        "not controllable: the mode at %.4g Hz (moving nodes %s) is not excited by any input, so "
                        "the parameters acting on it cannot be identified",
                        std::abs(lambda) / (2.0 * M_PI), names.c_str());
        }
    }
    rep.controllable = 1;
}

}  // namespace

namespace vibid {

void require_finalized(const vibid_model *model) {
    require_model(model);
    if (!model->frozen) throw_error(VIBID_E_STATE, "model is not finalized (call vibid_model_finalize)");
}

void check_signals_available(const vibid_model &m) {
    static const char *const qname[3] = {"displacement", "velocity", "acceleration"};
    const std::size_t n = m.nodes.size();
    auto measured = [&](std::size_t node) { return node == VIBID_BASE ? m.base_measured : m.nodes[node].measured; };
    // q: 0 displacement, 1 velocity, 2 acceleration. A derivative can be differenced
    // from a lower measured quantity, never integrated from a higher one.
    auto available = [&](std::size_t node, int q) {
        unsigned meas = measured(node);
        for (int k = 0; k <= q; ++k)
            if (meas & (1u << k)) return true;
        return false;
    };
    for (const auto &t : m.terms) {
        for (const auto &e : t.entries) {
            const Signal &s = e.signal;
            if (s.type == SignalType::Input) continue;
            int q = s.type == SignalType::Velocity ? 1 : s.type == SignalType::Acceleration ? 2 : 0;
            for (std::size_t node : {s.a, s.b}) {
                if (node == VIBID_GROUND || (node != VIBID_BASE && node >= n)) continue;
                if (!available(node, q))
                    throw_error(VIBID_E_DIMENSION,
                                "node '%s': %s needed by '%s' is not measured%s", end_name(m, node), qname[q],
                                t.name.c_str(),
                                q == 0 ? " (a displacement cannot be integrated from velocity or acceleration)"
                                       : " and cannot be differenced from a lower measured quantity");
            }
        }
    }
    if (m.discretization == VIBID_DISC_ZOH) {
        if (m.nonlinear)
            throw_error(VIBID_E_UNSUPPORTED, "ZOH discretization needs a linear model (it has a cubic spring); use "
                                             "central differences");
        if (m.base_damper)
            throw_error(VIBID_E_UNSUPPORTED,
                        "ZOH discretization: a damper (or cubic spring) between a node and the base is not "
                        "supported by the ZOH difference form (1.16) as built here: its regressor carries the base "
                        "displacement only, while such an element also needs the base's rate (an impulse "
                        "d (s_k - s_{k-1}) at every jump of a held base). This is a limit of the method, not of "
                        "identifiability: use discretization = \"central_difference\", which enters a held base "
                        "by its hold equivalents (regressor.h)");
        for (const auto &nd : m.nodes)
            if (!(nd.measured & VIBID_MEASURE_DISPLACEMENT))
                throw_error(VIBID_E_DIMENSION, "node '%s': ZOH discretization needs the displacement of every node",
                            nd.name.c_str());
        if (m.has_base && !(m.base_measured & VIBID_MEASURE_DISPLACEMENT))
            throw_error(VIBID_E_DIMENSION, "base: ZOH discretization needs the base displacement");
    }
}

}  // namespace vibid

extern "C" {

VIBID_API vibid_model *vibid_model_create(void) {
    return vibid::guard_create<vibid_model>(__func__, [] { return new vibid_model(); });
}

VIBID_API vibid_status vibid_model_reset(vibid_model *model) {
    VIBID_GUARD(require_model(model); *model = vibid_model(); return VIBID_OK;);
}

VIBID_API void vibid_model_destroy(vibid_model *model) { delete model; }

VIBID_API vibid_model *vibid_model_clone(const vibid_model *model) {
    return vibid::guard_create<vibid_model>(__func__, [&] {
        require_model(model);
        return new vibid_model(*model);
    });
}

VIBID_API vibid_status vibid_model_add_node(vibid_model *model, const char *name, double mass, int unknown,
                                            size_t *node_out) {
    VIBID_GUARD(
        require_editable(model);
        if (model->full_matrix) throw_error(VIBID_E_STATE, "model was given as full matrices");
        check_name(model, name, "node");
        if (!std::isfinite(mass)) throw_error(VIBID_E_NONFINITE, "node '%s': mass is not finite", name);
        if (!unknown && mass <= 0.0)
            throw_error(VIBID_E_OUT_OF_RANGE, "node '%s': known mass %g kg must be > 0", name, mass);
        if (unknown && mass < 0.0)
            throw_error(VIBID_E_OUT_OF_RANGE, "node '%s': nominal mass %g kg must be >= 0", name, mass);
        if (model->nodes.size() >= 4096) throw_error(VIBID_E_DIMENSION, "more than 4096 nodes");
        add_named(model, model->nodes, vibid::Node{name, mass, unknown != 0, 0}, 'n');
        if (node_out) *node_out = model->nodes.size() - 1;
        return VIBID_OK;);
}

VIBID_API vibid_status vibid_model_add_element(vibid_model *model, const char *name, vibid_element_kind kind,
                                               size_t node_a, size_t node_b, double value, int unknown) {
    VIBID_GUARD(
        require_editable(model);
        if (model->full_matrix) throw_error(VIBID_E_STATE, "model was given as full matrices");
        check_name(model, name, "element");
        const int k = vibid::enum_value(kind);
        if (k != VIBID_ELEMENT_SPRING && k != VIBID_ELEMENT_DAMPER && k != VIBID_ELEMENT_CUBIC_SPRING)
            throw_error(VIBID_E_OUT_OF_RANGE, "element '%s': unknown kind %d", name, k);
        const std::size_t n = model->nodes.size();
        if (node_a >= n)
            throw_error(VIBID_E_OUT_OF_RANGE, "element '%s': first end %zu is not a declared node (%zu nodes)", name,
                        node_a, n);
        if (node_b >= n && node_b != VIBID_GROUND && node_b != VIBID_BASE)
            throw_error(VIBID_E_OUT_OF_RANGE,
                        "element '%s': second end %zu is not a declared node, ground or base (%zu nodes)", name,
                        node_b, n);
        if (node_a == node_b) throw_error(VIBID_E_OUT_OF_RANGE, "element '%s' connects node '%s' to itself", name,
                                          model->nodes[node_a].name.c_str());
        if (!std::isfinite(value)) throw_error(VIBID_E_NONFINITE, "element '%s': value is not finite", name);
        if (kind != VIBID_ELEMENT_CUBIC_SPRING && value < 0.0)
            throw_error(VIBID_E_OUT_OF_RANGE, "element '%s': %s coefficient %g must be >= 0", name, kind_name(kind),
                        value);
        add_named(model, model->elements, vibid::Element{name, kind, node_a, node_b, value, unknown != 0}, 'e');
        return VIBID_OK;);
}

VIBID_API vibid_status vibid_model_add_input(vibid_model *model, const char *name, size_t node, double gain,
                                             int unknown, size_t *input_out) {
    VIBID_GUARD(
        require_editable(model);
        if (model->full_matrix) throw_error(VIBID_E_STATE, "model was given as full matrices");
        check_name(model, name, "input");
        if (node >= model->nodes.size())
            throw_error(VIBID_E_OUT_OF_RANGE, "input '%s': node %zu is not a declared node (%zu nodes)", name, node,
                        model->nodes.size());
        if (!std::isfinite(gain)) throw_error(VIBID_E_NONFINITE, "input '%s': gain is not finite", name);
        if (!unknown && gain == 0.0) throw_error(VIBID_E_OUT_OF_RANGE, "input '%s': known gain must be != 0", name);
        add_named(model, model->inputs, vibid::Input{name, node, gain, unknown != 0}, 'i');
        if (input_out) *input_out = model->inputs.size() - 1;
        return VIBID_OK;);
}

VIBID_API vibid_status vibid_model_add_disturbance(vibid_model *model, const char *name, size_t node,
                                                   double std_dev, size_t *index_out) {
    VIBID_GUARD(
        require_editable(model);
        if (model->full_matrix) throw_error(VIBID_E_STATE, "model was given as full matrices");
        check_name(model, name, "disturbance");
        if (node >= model->nodes.size())
            throw_error(VIBID_E_OUT_OF_RANGE, "disturbance '%s': node %zu is not a declared node (%zu nodes)", name,
                        node, model->nodes.size());
        if (!std::isfinite(std_dev) || std_dev < 0.0)
            throw_error(VIBID_E_OUT_OF_RANGE, "disturbance '%s': std_dev = %g must be >= 0 and finite (0 = unknown)",
                        name, std_dev);
        add_named(model, model->disturbances, vibid::Disturbance{name, node, std_dev}, 'd');
        if (index_out) *index_out = model->disturbances.size() - 1;
        return VIBID_OK;);
}

VIBID_API vibid_status vibid_model_disturbance_info(const vibid_model *model, size_t index,
                                                    vibid_disturbance_info *info) {
    VIBID_GUARD(
        require_model(model);
        if (!info) throw_error(VIBID_E_NULL_ARGUMENT, "info is NULL");
        if (index >= model->disturbances.size())
            throw_error(VIBID_E_OUT_OF_RANGE, "disturbance %zu of %zu", index, model->disturbances.size());
        const auto &w = model->disturbances[index];
        info->name = w.name.c_str();
        info->node = w.node;
        info->std_dev = w.std_dev;
        return VIBID_OK;);
}

VIBID_API vibid_status vibid_model_set_noise(vibid_model *model, size_t node, unsigned quantity, double std_dev) {
    VIBID_GUARD(
        require_editable(model);
        const int q = quantity_index(quantity);
        if (std::isnan(std_dev) || std::isinf(std_dev))
            throw_error(VIBID_E_NONFINITE, "noise std_dev is not finite (< 0 means unknown)");
        const double v = std_dev < 0.0 ? -1.0 : std_dev;
        if (node == VIBID_BASE) {
            model->base_noise[static_cast<std::size_t>(q)] = v;
        } else {
            if (node >= model->nodes.size())
                throw_error(VIBID_E_OUT_OF_RANGE, "node %zu is not a declared node (%zu nodes)", node,
                            model->nodes.size());
            model->node_noise.resize(model->nodes.size(), {{-1.0, -1.0, -1.0}});
            model->node_noise[node][static_cast<std::size_t>(q)] = v;
        }
        return VIBID_OK;);
}

VIBID_API vibid_status vibid_model_get_noise(const vibid_model *model, size_t node, unsigned quantity,
                                             double *std_dev) {
    VIBID_GUARD(
        require_model(model);
        if (!std_dev) throw_error(VIBID_E_NULL_ARGUMENT, "std_dev is NULL");
        const int q = quantity_index(quantity);
        if (node == VIBID_BASE) {
            *std_dev = model->base_noise[static_cast<std::size_t>(q)];
        } else {
            if (node >= model->nodes.size())
                throw_error(VIBID_E_OUT_OF_RANGE, "node %zu is not a declared node (%zu nodes)", node,
                            model->nodes.size());
            *std_dev = node < model->node_noise.size() ? model->node_noise[node][static_cast<std::size_t>(q)] : -1.0;
        }
        return VIBID_OK;);
}

VIBID_API vibid_status vibid_model_set_measured(vibid_model *model, size_t node, unsigned quantities) {
    VIBID_GUARD(
        require_editable(model);
        if (quantities & ~7u) throw_error(VIBID_E_OUT_OF_RANGE, "quantities 0x%x has bits other than VIBID_MEASURE_*",
                                          quantities);
        if (node == VIBID_BASE) {
            model->base_measured = quantities;
        } else {
            if (node >= model->nodes.size())
                throw_error(VIBID_E_OUT_OF_RANGE, "node %zu is not a declared node (%zu nodes)", node,
                            model->nodes.size());
            model->nodes[node].measured = quantities;
        }
        return VIBID_OK;);
}

VIBID_API vibid_status vibid_model_set_matrices(vibid_model *model, size_t n_dof, size_t n_inputs, const double *M,
                                                const double *D, const double *C, const double *B,
                                                unsigned unknown_mask) {
    VIBID_GUARD(
        require_editable(model);
        if (!model->nodes.empty() || !model->elements.empty() || !model->inputs.empty())
            throw_error(VIBID_E_STATE, "vibid_model_set_matrices needs an empty model");
        if (n_dof < 1 || n_dof > 256) throw_error(VIBID_E_DIMENSION, "n_dof = %zu outside 1..256", n_dof);
        if (n_inputs > 256) throw_error(VIBID_E_DIMENSION, "n_inputs = %zu outside 0..256", n_inputs);
        if (!M || !D || !C || (n_inputs > 0 && !B)) throw_error(VIBID_E_NULL_ARGUMENT, "M, D, C (and B) required");
        if (unknown_mask & ~15u) throw_error(VIBID_E_OUT_OF_RANGE, "unknown_mask 0x%x has bits other than 1|2|4|8",
                                             unknown_mask);
        if (!vibid::all_finite(M, n_dof * n_dof) || !vibid::all_finite(D, n_dof * n_dof) ||
            !vibid::all_finite(C, n_dof * n_dof) || (n_inputs && !vibid::all_finite(B, n_dof * n_inputs)))
            throw_error(VIBID_E_NONFINITE, "matrix with NaN or Inf");
        vibid_model built;
        built.full_matrix = true;
        for (std::size_t i = 0; i < n_dof; ++i)
            add_named(&built, built.nodes,
                      vibid::Node{"q" + std::to_string(i + 1), 0.0, false, VIBID_MEASURE_DISPLACEMENT}, 'n');
        for (std::size_t j = 0; j < n_inputs; ++j)
            add_named(&built, built.inputs, vibid::Input{"u" + std::to_string(j + 1), VIBID_GROUND, 1.0, false}, 'i');
        struct Mat {
            char letter;
            const double *data;
            unsigned bit;
            SignalType type;
            vibid_param_kind kind;
        };
        const Mat mats[3] = {{'M', M, 1u, SignalType::Acceleration, VIBID_PARAM_MASS},
                             {'D', D, 2u, SignalType::Velocity, VIBID_PARAM_DAMPING},
                             {'C', C, 4u, SignalType::Displacement, VIBID_PARAM_STIFFNESS}};
        for (const auto &mt : mats) {
            const bool unk = (unknown_mask & mt.bit) != 0;
            for (std::size_t j = 0; j < n_dof; ++j)
                for (std::size_t i = 0; i <= j; ++i) {
                    const double v = mt.data[i + j * n_dof];
                    if (!unk && v == 0.0) continue;  // known zeros contribute nothing
                    // "C1_2": a name of the safe set (vibid/cfgread.h) like every other, since
                    // it becomes a CSV column, a field key, a label ("C[1,2]" broke the CSV)
                    Term t{std::string(1, mt.letter) + std::to_string(i + 1) + "_" + std::to_string(j + 1), mt.kind, v,
                           unk, -1, {}};
                    t.entries.push_back(Entry{i, 1.0, Signal{mt.type, j, VIBID_GROUND}});
                    if (i != j) t.entries.push_back(Entry{j, 1.0, Signal{mt.type, i, VIBID_GROUND}});
                    built.matrix_terms.push_back(std::move(t));
                }
        }
        const bool unk_b = (unknown_mask & 8u) != 0;
        for (std::size_t j = 0; j < n_inputs; ++j)
            for (std::size_t i = 0; i < n_dof; ++i) {
                const double v = B[i + j * n_dof];
                if (!unk_b && v == 0.0) continue;
                Term t{"B" + std::to_string(i + 1) + "_" + std::to_string(j + 1), VIBID_PARAM_GAIN, v, unk_b, -1, {}};
                t.entries.push_back(Entry{i, -1.0, Signal{SignalType::Input, j, 0}});
                built.matrix_terms.push_back(std::move(t));
            }
        built.discretization = model->discretization;
        *model = std::move(built);
        return VIBID_OK;);
}

VIBID_API vibid_status vibid_model_set_hold(vibid_model *model, size_t input, vibid_hold hold) {
    VIBID_GUARD(
        require_editable(model);
        const int hv = vibid::enum_value(hold);
        if (hv != VIBID_HOLD_SMOOTH && hv != VIBID_HOLD_ZOH)
            throw_error(VIBID_E_OUT_OF_RANGE, "hold %d unknown (VIBID_HOLD_SMOOTH or VIBID_HOLD_ZOH)", hv);
        if (input == VIBID_BASE)
            model->base_hold = hold;
        else if (input < model->inputs.size())
            model->inputs[input].hold = hold;
        else
            throw_error(VIBID_E_OUT_OF_RANGE, "input %zu: the model has %zu inputs (or pass VIBID_BASE)", input,
                        model->inputs.size());
        return VIBID_OK;);
}

VIBID_API vibid_status vibid_model_get_hold(const vibid_model *model, size_t input, vibid_hold *hold) {
    if (!model || !hold) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "model and hold are required");
    if (input == VIBID_BASE) {
        *hold = model->base_hold;
        return VIBID_OK;
    }
    if (input >= model->inputs.size())
        return VIBID_FAIL(VIBID_E_OUT_OF_RANGE, "input %zu: the model has %zu inputs (or pass VIBID_BASE)", input,
                          model->inputs.size());
    *hold = model->inputs[input].hold;
    return VIBID_OK;
}

VIBID_API vibid_status vibid_model_set_discretization(vibid_model *model, vibid_discretization disc) {
    VIBID_GUARD(
        require_editable(model);
        const int dv = vibid::enum_value(disc);
        if (dv != VIBID_DISC_CENTRAL_DIFFERENCE && dv != VIBID_DISC_ZOH)
            throw_error(VIBID_E_OUT_OF_RANGE, "discretization %d unknown", dv);
        model->discretization = disc;
        return VIBID_OK;);
}

VIBID_API vibid_status vibid_model_finalize(vibid_model *model) {
    VIBID_GUARD(
        require_editable(model);
        if (model->nodes.empty()) throw_error(VIBID_E_DIMENSION, "model has no node");
        vibid_model work = *model;  // on failure the model stays as it was
        derive_structure(work);
        if (!work.full_matrix) {
            std::vector<int> touched(work.nodes.size(), 0);
            for (const auto &e : work.elements) {
                touched[e.a] = 1;
                if (e.b < work.nodes.size()) touched[e.b] = 1;
            }
            for (const auto &u : work.inputs) touched[u.node] = 1;
            for (const auto &w : work.disturbances) touched[w.node] = 1;
            for (std::size_t i = 0; i < work.nodes.size(); ++i)
                if (!touched[i])
                    throw_error(VIBID_E_OUT_OF_RANGE, "node '%s' is not connected: no element and no input touches it",
                                work.nodes[i].name.c_str());
            if (work.base_measured && !work.has_base)
                throw_error(VIBID_E_OUT_OF_RANGE, "base motion is measured but no element connects to the base");
        }
        work.node_noise.resize(work.nodes.size(), {{-1.0, -1.0, -1.0}});
        work.frozen = true;
        *model = std::move(work);
        return VIBID_OK;);
}

VIBID_API vibid_status vibid_model_check_identifiable(const vibid_model *model, vibid_identifiability *report) {
    vibid_identifiability local{};
    vibid_identifiability &rep = report ? *report : local;
    rep = vibid_identifiability{};
    VIBID_GUARD(
        vibid::require_finalized(model);
        const vibid_model &m = *model;
        if (m.param_term.empty())
            throw_error(VIBID_E_OUT_OF_RANGE, "nothing unknown: every mass, element and gain is known");
        vibid::check_signals_available(m);
        // Which of M, D, C, B is known and regular (ref. [7]).
        bool known[4] = {true, true, true, true};
        for (const auto &t : m.terms) {
            if (!t.unknown) continue;
            if (t.kind == VIBID_PARAM_MASS) known[0] = false;
            if (t.kind == VIBID_PARAM_DAMPING) known[1] = false;
            if (t.kind == VIBID_PARAM_STIFFNESS) known[2] = false;
            if (t.kind == VIBID_PARAM_GAIN) known[3] = false;
        }
        Assembled a = assemble(m, nullptr, -1);
        if (known[0] && regular(a.M)) rep.known_regular |= 1;
        if (known[1] && regular(a.D)) rep.known_regular |= 2;
        if (known[2] && regular(a.C)) rep.known_regular |= 4;
        if (known[3] && regular(a.B)) rep.known_regular |= 8;
        bool any_known = false;
        for (const auto &t : m.terms)
            if (!t.unknown && t.value != 0.0) any_known = true;
        if (!any_known)
            throw_error(VIBID_E_NOT_IDENTIFIABLE,
                        "nothing known fixes the scale: with every mass, element and gain unknown, all parameters "
                        "times any factor fit the data equally well; make one known");
        if (m.full_matrix && rep.known_regular == 0)
            throw_error(VIBID_E_NOT_IDENTIFIABLE,
                        "none of M, D, C, B is known and regular (ref. [7]); make one of them known");
        check_generic_rank(m, rep);
        check_controllable(m, rep, true);
        return VIBID_OK;);
}

VIBID_API vibid_status vibid_model_get_dims(const vibid_model *model, vibid_model_dims *dims) {
    VIBID_GUARD(
        vibid::require_finalized(model);
        if (!dims) throw_error(VIBID_E_NULL_ARGUMENT, "dims is NULL");
        dims->n_dof = model->nodes.size();
        dims->n_inputs = model->inputs.size();
        dims->n_params = model->param_term.size();
        dims->n_channels = model->channels.size();
        dims->n_elements = model->elements.size();
        dims->has_base = model->has_base ? 1 : 0;
        dims->nonlinear = model->nonlinear ? 1 : 0;
        dims->discretization = model->discretization;
        dims->n_disturbances = model->disturbances.size();
        return VIBID_OK;);
}

VIBID_API vibid_status vibid_model_param_info(const vibid_model *model, size_t index, vibid_param_info *info) {
    VIBID_GUARD(
        vibid::require_finalized(model);
        if (!info) throw_error(VIBID_E_NULL_ARGUMENT, "info is NULL");
        if (index >= model->param_term.size())
            throw_error(VIBID_E_OUT_OF_RANGE, "parameter %zu of %zu", index, model->param_term.size());
        const Term &t = model->terms[model->param_term[index]];
        info->name = t.name.c_str();
        info->kind = t.kind;
        info->nominal = t.value;
        return VIBID_OK;);
}

VIBID_API vibid_status vibid_model_channel_info(const vibid_model *model, size_t index, vibid_channel_info *info) {
    VIBID_GUARD(
        vibid::require_finalized(model);
        if (!info) throw_error(VIBID_E_NULL_ARGUMENT, "info is NULL");
        if (index >= model->channels.size())
            throw_error(VIBID_E_OUT_OF_RANGE, "channel %zu of %zu", index, model->channels.size());
        const auto &c = model->channels[index];
        info->name = c.name.c_str();
        info->kind = c.kind;
        info->index = c.index;
        return VIBID_OK;);
}

VIBID_API vibid_status vibid_model_find_node(const vibid_model *model, const char *name, size_t *node_out) {
    VIBID_GUARD(
        require_model(model);
        if (!name || !node_out) throw_error(VIBID_E_NULL_ARGUMENT, "name and node_out are required");
        const auto it = model->names.find(name);
        if (it != model->names.end() && it->second.first == 'n') {
            *node_out = it->second.second;
            return VIBID_OK;
        }
        throw_error(VIBID_E_OUT_OF_RANGE, "no node named '%s'", name););
}

VIBID_API vibid_status vibid_model_node_name(const vibid_model *model, size_t node, const char **name_out) {
    VIBID_GUARD(
        require_model(model);
        if (!name_out) throw_error(VIBID_E_NULL_ARGUMENT, "name_out is NULL");
        if (node >= model->nodes.size()) throw_error(VIBID_E_OUT_OF_RANGE, "node %zu of %zu", node, model->nodes.size());
        *name_out = model->nodes[node].name.c_str();
        return VIBID_OK;);
}

VIBID_API vibid_status vibid_model_nominal(const vibid_model *model, double *theta) {
    VIBID_GUARD(
        vibid::require_finalized(model);
        if (!theta) throw_error(VIBID_E_NULL_ARGUMENT, "theta is NULL");
        for (std::size_t i = 0; i < model->param_term.size(); ++i) theta[i] = model->terms[model->param_term[i]].value;
        return VIBID_OK;);
}

VIBID_API vibid_status vibid_model_assemble(const vibid_model *model, const double *theta, double *M, double *D,
                                            double *C, double *B, double *d_base, double *c_base) {
    VIBID_GUARD(
        vibid::require_finalized(model);
        if (theta && !vibid::all_finite(theta, model->param_term.size()))
            throw_error(VIBID_E_NONFINITE, "theta has NaN or Inf");
        assemble_into(*model, theta, -1, M, D, C, model->inputs.empty() ? nullptr : B, d_base, c_base);
        return VIBID_OK;);
}

VIBID_API vibid_status vibid_model_structure(const vibid_model *model, size_t index, double *M_i, double *D_i,
                                             double *C_i, double *B_i, double *d_base_i, double *c_base_i) {
    VIBID_GUARD(
        vibid::require_finalized(model);
        if (index >= model->param_term.size())
            throw_error(VIBID_E_OUT_OF_RANGE, "parameter %zu of %zu", index, model->param_term.size());
        assemble_into(*model, nullptr, static_cast<long>(index), M_i, D_i, C_i,
                      model->inputs.empty() ? nullptr : B_i, d_base_i, c_base_i);
        return VIBID_OK;);
}

// Real-time path: no exceptions, no allocation.
VIBID_API vibid_status vibid_model_forces(const vibid_model *model, const double *theta, const double *y,
                                          const double *yd, const double *base, const double *u, double *f_out) {
    if (!model || !y || !yd || !f_out) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "model, y, yd and f_out are required");
    if (!model->frozen) return VIBID_FAIL(VIBID_E_STATE, "model is not finalized");
    if (model->has_base && !base) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "model has a base: base = {s, s'} required");
    if (!model->inputs.empty() && !u) return VIBID_FAIL(VIBID_E_NULL_ARGUMENT, "model has inputs: u required");
    const std::size_t n = model->nodes.size();
    for (std::size_t i = 0; i < n; ++i) f_out[i] = 0.0;
    auto coord = [&](std::size_t node, int q) -> double {
        if (node == VIBID_GROUND) return 0.0;
        if (node == VIBID_BASE) return base[q];
        return q == 0 ? y[node] : yd[node];
    };
    for (const auto &t : model->terms) {
        const double v = vibid::term_value(t, theta);
        for (const auto &e : t.entries) {
            const Signal &s = e.signal;
            double val;
            switch (s.type) {
            case SignalType::Acceleration: continue;  // inertia: the caller's M y''
            case SignalType::Input: val = u[s.a]; break;
            case SignalType::Velocity: val = coord(s.a, 1) - coord(s.b, 1); break;
            case SignalType::Displacement: val = coord(s.a, 0) - coord(s.b, 0); break;
            case SignalType::Cubic: {
                const double r = coord(s.a, 0) - coord(s.b, 0);
                val = r * r * r;
                break;
            }
            default: continue;
            }
            f_out[e.row] -= e.coef * v * val;
        }
    }
    return VIBID_OK;
}

}  // extern "C"
