/* vibid/model.h: description of a mechanical vibration system (a test stand) as a
 * lumped network, and its structured form (4.1).
 *
 * A model is built in two phases:
 *  1. Description. Nodes (point masses, one coordinate each), elements between two
 *     nodes, a node and ground, or a node and the moving base (linear spring, viscous
 *     damper, cubic spring), force inputs on nodes, and which quantities are measured.
 *     Every scalar (mass, stiffness, damping, cubic coefficient, input gain) is either
 *     known or unknown. Alternatively the full matrices M, D, C, B of (1.4)/(1.7) can be
 *     given with a mask of the unknown ones (vibid_model_set_matrices).
 *  2. vibid_model_finalize checks the description for consistency (messages name the
 *     item), numbers the unknown scalars 0..p-1 in declaration order (nodes' masses, then
 *     elements, then input gains) and derives the structured form (4.1):
 *        sum_i m_i M_i y'' + sum_j d_j D_j y' + sum_k c_k C_k y + sum_l eps_l g_l(y, s)
 *          = B u + (base terms)
 *     with each scalar (known or unknown) times a known sparse structure matrix.
 *     After finalize the model is frozen (add/set calls give VIBID_E_STATE).
 *
 * Equation of motion, one row per node i (n = number of nodes = degrees of freedom):
 *     m_i y_i'' + sum over elements e touching i of  sign(e, i) f_e  =  sum_j b_j u_j [input j on i]
 *   element e between a and b, relative coordinate r = y_a - y_b (y_ground = 0,
 *   y_base = s, the base displacement):
 *     spring        f = c r         c   in N/m       (>= 0)
 *     damper        f = d r'        d   in N s/m     (>= 0)
 *     cubic spring  f = eps r^3     eps in N/m^3     (any sign: hardening > 0, softening < 0)
 *   sign(e, a) = +1, sign(e, b) = -1. Example 2 of the paper (4.2) is: nodes m1, m2;
 *   spring c1 and damper d between m1 and m2; spring c2 and cubic spring eps between m2
 *   and the base.
 * Units are SI in this header; any consistent set works (e.g. mm, N, s, t), the library
 * never converts.
 *
 * Channels: the per-sample vector that the regressor and identification objects read has
 * a fixed layout, vibid_model_channel_info describes it:
 *   for each node in declaration order: displacement (m), velocity (m/s), acceleration
 *   (m/s^2), each only if measured; then the base: displacement, velocity, acceleration,
 *   each only if measured; then every force input u_j (input units, the gain b_j turns
 *   them into N).
 *
 * Identifiability (ref. [7] of the paper; vibid_model_check_identifiable): for a model
 * given as full matrices the paper's condition is applied literally (one of M, D, C, B
 * known and regular, and (A, B) controllable). For a lumped network the structure
 * already pins many entries, so the condition used is: the generic (structural) rank of
 * the regressor is full, some known term fixes the scale, and the linearized model is
 * controllable from its inputs (forces and base motion). Which of M, D, C, B is known
 * and regular is reported in either case.
 */
#ifndef VIBID_MODEL_H
#define VIBID_MODEL_H

#include <vibid/common.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct vibid_model vibid_model;

/* Pseudo node indices for the second end of an element. */
#define VIBID_GROUND ((size_t)-1) /* fixed reference, displacement 0 */
#define VIBID_BASE ((size_t)-2)   /* moving base (support), displacement s(t) */

typedef enum vibid_element_kind {
    VIBID_ELEMENT_SPRING = 0,      /* f = c r,     c in N/m   */
    VIBID_ELEMENT_DAMPER = 1,      /* f = d r',    d in N s/m */
    VIBID_ELEMENT_CUBIC_SPRING = 2 /* f = eps r^3, eps in N/m^3 (3.5), (4.2) */
} vibid_element_kind;

/* Bit mask of measured quantities of a node or of the base. */
#define VIBID_MEASURE_DISPLACEMENT 1u
#define VIBID_MEASURE_VELOCITY 2u
#define VIBID_MEASURE_ACCELERATION 4u

/* How the continuous model becomes a regression (per model; see discretize.h):
 *  CENTRAL_DIFFERENCE (1.17): derivatives that are not measured are replaced by central
 *    differences, the structured unknowns are estimated directly. Works for nonlinear
 *    (cubic) models and for any mix of measured displacement/velocity/acceleration.
 *    Bias O((omega h)^2 / 12) on the parameters, omega the highest frequency that
 *    matters (about 0.2 % at 20 samples per period of the highest mode).
 *  ZOH (1.9)-(1.16): the second-order difference form (1.16) is estimated without
 *    structure from displacements and inputs, then mapped back to continuous M^-1 C,
 *    M^-1 D, M^-1 B by the matrix logarithm and projected onto the structured unknowns.
 *    Exact for linear models whose inputs are piecewise constant over each sample
 *    interval (1.10); linear models only, all node displacements must be measured,
 *    more parameters in the regression (2n + 2r per output) and a nonlinear back
 *    transformation. */
typedef enum vibid_discretization {
    VIBID_DISC_CENTRAL_DIFFERENCE = 0,
    VIBID_DISC_ZOH = 1
} vibid_discretization;

/* How an input (a force input u_j, or the base displacement s) behaves between samples.
 *  SMOOTH  the samples are taken from a continuous, smooth signal (an analog sensor, a
 *          sine from a signal generator). Default.
 *  ZOH     the signal is held constant over [t_k, t_k + h) and jumps at t_k (a DAC
 *          output, a controller's set point updated once per sample) (1.10). A held base
 *          displacement jumps by s_k - s_{k-1} at t_k: a damper (or a cubic spring's
 *          rate) to the base transmits that jump as an impulse d (s_k - s_{k-1}), i.e.
 *          the node's velocity jumps by d (s_k - s_{k-1}) / m. A held signal is, to the
 *          system, its sample sequence delayed by h/2 and low-passed by sinc(omega h / 2):
 *          treated as if sampled at the instant, it biases every damping (a phase error
 *          of omega h / 2). The identification accounts for it (regressor.h), and the
 *          simulator produces it (docs/sim.md). */
typedef enum vibid_hold {
    VIBID_HOLD_SMOOTH = 0,
    VIBID_HOLD_ZOH = 1
} vibid_hold;

typedef enum vibid_param_kind {
    VIBID_PARAM_MASS = 0,      /* kg (an entry of M for full-matrix models) */
    VIBID_PARAM_DAMPING = 1,   /* N s/m (an entry of D) */
    VIBID_PARAM_STIFFNESS = 2, /* N/m (an entry of C) */
    VIBID_PARAM_CUBIC = 3,     /* N/m^3 */
    VIBID_PARAM_GAIN = 4       /* N per input unit (an entry of B) */
} vibid_param_kind;

typedef enum vibid_channel_kind {
    VIBID_CHANNEL_DISPLACEMENT = 0, /* m */
    VIBID_CHANNEL_VELOCITY = 1,     /* m/s */
    VIBID_CHANNEL_ACCELERATION = 2, /* m/s^2 */
    VIBID_CHANNEL_INPUT = 3         /* input units */
} vibid_channel_kind;

typedef struct vibid_model_dims {
    size_t n_dof;       /* n: nodes (coordinates) */
    size_t n_inputs;    /* r: force inputs */
    size_t n_params;    /* p: unknown scalars */
    size_t n_channels;  /* length of the per-sample channel vector */
    size_t n_elements;  /* elements (0 for full-matrix models) */
    int has_base;       /* non-zero if an element connects to the base */
    int nonlinear;      /* non-zero if a cubic spring is present */
    vibid_discretization discretization;
    size_t n_disturbances; /* unmeasured random forces (vibid_model_add_disturbance) */
} vibid_model_dims;

typedef struct vibid_disturbance_info {
    const char *name;   /* lives as long as the model */
    size_t node;        /* node the force acts on */
    double std_dev;     /* N: standard deviation of the held samples; 0 = unknown (estimated) */
} vibid_disturbance_info;

typedef struct vibid_param_info {
    const char *name;      /* e.g. "c1" (element name), "m2" (node name for a mass),
                              "f1" (input name for a gain), "C1_2" (full matrices: row 1,
                              column 2, 1-based).
                              Lives as long as the model. */
    vibid_param_kind kind;
    double nominal;        /* value given in the description (start/true value, may be 0 = not given) */
} vibid_param_info;

typedef struct vibid_channel_info {
    const char *name;        /* "<node>.displacement", "base.velocity", "<input>", ... lives as long as the model */
    vibid_channel_kind kind;
    size_t index;            /* node index, VIBID_BASE, or input index for VIBID_CHANNEL_INPUT */
} vibid_channel_info;

/* Report of vibid_model_check_identifiable. */
typedef struct vibid_identifiability {
    int known_regular;      /* bit mask of the matrices that are fully known and regular:
                               1 = M, 2 = D, 4 = C, 8 = B (B: square and regular) */
    int controllable;       /* non-zero if (A, [B, base]) is controllable at the nominal values */
    size_t generic_rank;    /* structural rank of the regressor, p if identifiable */
} vibid_identifiability;

/* Creates an empty model (nothing declared, discretization CENTRAL_DIFFERENCE).
 * NULL only when out of memory. */
VIBID_API vibid_model *vibid_model_create(void);

/* Forgets the whole description; the model is as new (and no longer frozen). */
VIBID_API vibid_status vibid_model_reset(vibid_model *model);

/* Frees the model. NULL is allowed. Objects created from a model (regressor,
 * identification) keep their own copy, so the model may be destroyed before them. */
VIBID_API void vibid_model_destroy(vibid_model *model);

/* Copy of a model in any state (e.g. to vary one parameter). NULL on failure. */
VIBID_API vibid_model *vibid_model_clone(const vibid_model *model);

/* Declares a node (a point mass with one coordinate).
 *   name    1..63 printable characters, unique among nodes, not "ground"/"base".
 *   mass    kg; known: > 0 and finite. Unknown: nominal value >= 0 (0 = not given),
 *           used for simulation and for the controllability check only.
 *   unknown 0 = mass known, non-zero = mass to be estimated.
 *   node_out receives the node index (0-based, declaration order); may be NULL. */
VIBID_API vibid_status vibid_model_add_node(vibid_model *model, const char *name, double mass, int unknown,
                                            size_t *node_out);

/* Declares an element between node_a (a node index) and node_b (a node index,
 * VIBID_GROUND or VIBID_BASE), node_a != node_b.
 *   name   1..63 printable characters, unique among elements, inputs and nodes.
 *   value  known: the coefficient (units see vibid_element_kind; springs and dampers
 *          >= 0); unknown: nominal value (0 = not given).
 * An index that is not a declared node gives VIBID_E_OUT_OF_RANGE naming the element. */
VIBID_API vibid_status vibid_model_add_element(vibid_model *model, const char *name, vibid_element_kind kind,
                                               size_t node_a, size_t node_b, double value, int unknown);

/* Declares a force input u_j acting on node with gain b_j (force = b_j u_j, N).
 *   gain   known: N per input unit, != 0; unknown: nominal value (0 = not given).
 *   input_out receives the input index j (0-based); may be NULL. */
VIBID_API vibid_status vibid_model_add_input(vibid_model *model, const char *name, size_t node, double gain,
                                             int unknown, size_t *input_out);

/* Declares an unmeasured random force w on node (the paper's Q w of (1.7)/(3.11)): a
 * force nobody measures, e.g. the excitation of a machine in service. Its samples are
 * white, zero-mean, with standard deviation std_dev (N), and each is held over its
 * sample interval [t_k, t_k + h) (the discrete white noise of the paper's example 3;
 * vibid-sim produces it so, docs/sim.md). R_w = std_dev^2.
 *   name     as for elements (unique among nodes, elements, inputs and disturbances).
 *   std_dev  > 0: known intensity; 0: unknown, estimated from the data by the filter
 *            (identify.h, estimator EKF). Finite.
 * A disturbance has no channel. Only the state-space estimator (VIBID_ESTIMATOR_EKF)
 * uses it; the regression estimators treat it as part of the equation error.
 * index_out receives its index (0-based); may be NULL. */
VIBID_API vibid_status vibid_model_add_disturbance(vibid_model *model, const char *name, size_t node,
                                                   double std_dev, size_t *index_out);

/* Disturbance `index` (0..n_disturbances-1), any state. */
VIBID_API vibid_status vibid_model_disturbance_info(const vibid_model *model, size_t index,
                                                    vibid_disturbance_info *info);

/* Standard deviation of the white measurement noise of one measured quantity of node
 * (index or VIBID_BASE): quantity one VIBID_MEASURE_* bit, std_dev >= 0 in the channel's
 * units (m, m/s, m/s^2), or < 0 for "unknown" (the default: the state-space estimator
 * estimates it from the data, identify.h). May be set before the quantity is declared
 * measured; it only matters for a measured one. */
VIBID_API vibid_status vibid_model_set_noise(vibid_model *model, size_t node, unsigned quantity, double std_dev);
/* The declared noise of that quantity (< 0: unknown); any state. */
VIBID_API vibid_status vibid_model_get_noise(const vibid_model *model, size_t node, unsigned quantity,
                                             double *std_dev);

/* Sets which quantities of node (index or VIBID_BASE) are measured: a combination of
 * VIBID_MEASURE_* bits (0 = nothing). Default: nothing measured. */
VIBID_API vibid_status vibid_model_set_measured(vibid_model *model, size_t node, unsigned quantities);

/* Full-matrix model (1.4)/(1.7): M y'' + D y' + C y = B u, on an empty model.
 *   n_dof 1..256, n_inputs 0..256; M, D, C n x n (column-major, symmetric: only the
 *   upper triangle is read), B n x n_inputs (may be NULL when n_inputs = 0).
 *   unknown_mask bits 1 = M, 2 = D, 4 = C, 8 = B: the whole matrix is unknown. Unknown
 *   symmetric matrices contribute n (n + 1) / 2 parameters (upper triangle, column by
 *   column), an unknown B n * n_inputs; the given values are then nominal values.
 * Creates nodes "q1".."qn" (all displacements measured) and inputs "u1".."ur". */
VIBID_API vibid_status vibid_model_set_matrices(vibid_model *model, size_t n_dof, size_t n_inputs,
                                                const double *M, const double *D, const double *C,
                                                const double *B, unsigned unknown_mask);

/* Declares how input `input` (an input index, or VIBID_BASE for the base displacement)
 * behaves between samples (vibid_hold; default SMOOTH). On an editable model; the base
 * may be declared before any element touches it. */
VIBID_API vibid_status vibid_model_set_hold(vibid_model *model, size_t input, vibid_hold hold);
/* The declaration of input `input` (index or VIBID_BASE); works in any state. */
VIBID_API vibid_status vibid_model_get_hold(const vibid_model *model, size_t input, vibid_hold *hold);

/* Chooses the discretization used for identification (default CENTRAL_DIFFERENCE). */
VIBID_API vibid_status vibid_model_set_discretization(vibid_model *model, vibid_discretization disc);

/* Checks the description and freezes it. Rejections (VIBID_E_OUT_OF_RANGE or
 * VIBID_E_DIMENSION, message naming the item): no node; a node that no element and no
 * input touches; a measured quantity on the base when nothing connects to the base.
 * Nothing here concerns identification: a fully known model is a valid simulation
 * model. */
VIBID_API vibid_status vibid_model_finalize(vibid_model *model);

/* Identification checks, before any sample (needs a finalized model):
 *  - at least one unknown (VIBID_E_OUT_OF_RANGE "nothing unknown"),
 *  - every signal the equations need can be formed from the measured channels
 *    (VIBID_E_DIMENSION naming node, quantity and the element that needs it): a
 *    displacement must be measured where a spring or cubic spring acts; a velocity must
 *    be measured or differentiated from a measured displacement where a damper acts; an
 *    acceleration must be measured or differentiated from a measured velocity or
 *    displacement at every node; ZOH needs every node's displacement and a linear model,
 *  - identifiability (VIBID_E_NOT_IDENTIFIABLE naming the parameters that cannot be
 *    separated, or the uncontrolled nodes).
 * report may be NULL; it is filled in whenever the checks got that far. */
VIBID_API vibid_status vibid_model_check_identifiable(const vibid_model *model, vibid_identifiability *report);

/* ---- queries (finalized model) ---- */
VIBID_API vibid_status vibid_model_get_dims(const vibid_model *model, vibid_model_dims *dims);
VIBID_API vibid_status vibid_model_param_info(const vibid_model *model, size_t index, vibid_param_info *info);
VIBID_API vibid_status vibid_model_channel_info(const vibid_model *model, size_t index, vibid_channel_info *info);
/* Node index of name; VIBID_E_OUT_OF_RANGE if there is none. Works before finalize. */
VIBID_API vibid_status vibid_model_find_node(const vibid_model *model, const char *name, size_t *node_out);
/* Name of node i (lives as long as the model). */
VIBID_API vibid_status vibid_model_node_name(const vibid_model *model, size_t node, const char **name_out);

/* Nominal values of the unknowns (p), as declared. */
VIBID_API vibid_status vibid_model_nominal(const vibid_model *model, double *theta);

/* Linear matrices of (1.4)/(1.7) plus the base coupling, for parameter values theta
 * (p; NULL = nominal values):
 *     M y'' + D y' + C y = B u + d_base s' + c_base s      (+ cubic terms, not here)
 *   M, D, C n x n; B n x r; d_base, c_base n. Any output may be NULL. */
VIBID_API vibid_status vibid_model_assemble(const vibid_model *model, const double *theta, double *M, double *D,
                                            double *C, double *B, double *d_base, double *c_base);

/* Structure matrices of unknown i in (4.1): the derivative of the assembled matrices
 * with respect to theta_i (shapes as in vibid_model_assemble; any may be NULL). Zero
 * for a cubic coefficient, whose term is nonlinear. */
VIBID_API vibid_status vibid_model_structure(const vibid_model *model, size_t index, double *M_i, double *D_i,
                                             double *C_i, double *B_i, double *d_base_i, double *c_base_i);

/* Right-hand side of M y'' = f for simulation (all forces but inertia):
 *   f = B u + d_base s' + c_base s - D y' - C y - cubic terms.
 *   theta p (NULL = nominal), y, yd n (m, m/s), base[2] = {s, s'} (may be NULL without
 *   base), u r (may be NULL without inputs), f_out n (N).
 * Allocates nothing; cost O(number of elements + n r). */
VIBID_API vibid_status vibid_model_forces(const vibid_model *model, const double *theta, const double *y,
                                          const double *yd, const double *base, const double *u, double *f_out);

#ifdef __cplusplus
}
#endif
#endif
