// model_internal.hpp: the C++ side of vibid_model, shared by model.cpp, regressor.cpp,
// modal.cpp and identify.cpp (never installed).
//
// Every scalar of the description (a node's mass, an element's coefficient, an input's
// gain, an entry of a full matrix) becomes one Term: value times a list of Entries,
// each "coefficient times a signal, in equation row". The equation of motion is
//     sum over terms  value_t * sum over entries  coef * signal  = 0
// (inputs enter with coef -1, so B u ends up on the right-hand side). That is the
// structured form (4.1) in its most direct machine form: an unknown term contributes a
// regressor column, a known term goes into the target.
#pragma once

#include <vibid/model.h>

#include <array>
#include <cstddef>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

namespace vibid {

enum class SignalType { Displacement, Velocity, Acceleration, Cubic, Input };

// Signal of a relative coordinate r = y_a - y_b (b may be VIBID_GROUND or VIBID_BASE);
// for Input, a is the input index and b is unused.
struct Signal {
    SignalType type;
    std::size_t a;
    std::size_t b;
};

struct Entry {
    std::size_t row;
    double coef;
    Signal signal;
};

struct Term {
    std::string name;
    vibid_param_kind kind;
    double value;   // known value, or nominal value of an unknown
    bool unknown;
    long param;     // index into theta, -1 when known
    std::vector<Entry> entries;
};

struct Node {
    std::string name;
    double mass;
    bool unknown;
    unsigned measured;
};

struct Element {
    std::string name;
    vibid_element_kind kind;
    std::size_t a, b;
    double value;
    bool unknown;
};

struct Input {
    std::string name;
    std::size_t node;  // VIBID_GROUND for inputs of a full-matrix model (B holds the coupling)
    double gain;
    bool unknown;
    vibid_hold hold = VIBID_HOLD_SMOOTH;
};

// Unmeasured random force (vibid_model_add_disturbance).
struct Disturbance {
    std::string name;
    std::size_t node;
    double std_dev;  // N; 0 = unknown
};

struct Channel {
    std::string name;
    vibid_channel_kind kind;
    std::size_t index;
};

constexpr long kNoChannel = -1;

}  // namespace vibid

struct vibid_model {
    // description
    std::vector<vibid::Node> nodes;
    std::vector<vibid::Element> elements;
    std::vector<vibid::Input> inputs;
    std::vector<vibid::Term> matrix_terms;  // full-matrix models only
    std::vector<vibid::Disturbance> disturbances;
    // Every name -> what carries it ('n' node, 'e' element, 'i' input, 'd' disturbance) and
    // its index there: the duplicate check and vibid_model_find_node in constant time (a
    // stand of 10^5 elements took 61 s to load when both walked every list, issue 30).
    std::unordered_map<std::string, std::pair<char, std::size_t>> names;
    unsigned base_measured = 0;
    // Measurement noise std per quantity (disp, vel, acc) of each node and of the base;
    // < 0 = unknown (vibid_model_set_noise). node_noise grows with the nodes.
    std::vector<std::array<double, 3>> node_noise;
    std::array<double, 3> base_noise{{-1.0, -1.0, -1.0}};
    vibid_hold base_hold = VIBID_HOLD_SMOOTH;
    bool full_matrix = false;
    vibid_discretization discretization = VIBID_DISC_CENTRAL_DIFFERENCE;
    bool frozen = false;

    // derived by finalize
    std::vector<vibid::Term> terms;
    std::vector<std::size_t> param_term;              // theta index -> term index
    std::vector<vibid::Channel> channels;
    std::vector<std::array<long, 3>> node_channel;    // [disp, vel, acc] channel or kNoChannel
    std::array<long, 3> base_channel{{vibid::kNoChannel, vibid::kNoChannel, vibid::kNoChannel}};
    std::vector<long> input_channel;
    bool has_base = false;
    bool base_damper = false;   // a damper or cubic spring touches the base
    bool nonlinear = false;
};

namespace vibid {

// Throws vibid::Error unless the model is finalized.
void require_finalized(const vibid_model *model);

// Value of term t for parameter vector theta (nullptr = nominal values).
inline double term_value(const Term &t, const double *theta) {
    return (t.unknown && theta) ? theta[t.param] : t.value;
}

// Checks that every signal the equations need can be formed from the measured channels
// (and, for ZOH, that the model is linear with all displacements measured); throws
// vibid::Error naming node, quantity and the element that needs it.
void check_signals_available(const vibid_model &model);

}  // namespace vibid
