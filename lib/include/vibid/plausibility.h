/* vibid/plausibility.h: is an estimate physically possible?
 *
 * One rule for every program (vibidd, the examples, a binding): an identified parameter
 * vector theta and the modal parameters computed from it (vibid_model_modal) are
 * "implausible" when any of the following holds. Each rule has its own bit; the bits are
 * reported per parameter, per mode and as a summary.
 *
 *  parameters (theta, p values in the model's parameter order, model units):
 *   VIBID_IMPLAUSIBLE_NONFINITE  theta_k is NaN or Inf.
 *   VIBID_IMPLAUSIBLE_MASS       a mass <= 0 kg,
 *   VIBID_IMPLAUSIBLE_DAMPING    a damping coefficient <= 0 N s/m,
 *   VIBID_IMPLAUSIBLE_STIFFNESS  a stiffness <= 0 N/m.
 *       Lumped networks (model.h): every unknown node mass, damper and linear spring.
 *       Full-matrix models (vibid_model_set_matrices): only the diagonal entries
 *       "Mi_i", "Di_i", "Ci_i"; off-diagonal entries (couplings) may have any sign.
 *       Cubic coefficients (VIBID_PARAM_CUBIC: hardening > 0, softening < 0) and input
 *       gains (VIBID_PARAM_GAIN: the sign is the sensor's/actuator's convention) are
 *       never sign-constrained. Zero counts as implausible: no estimate is exactly 0
 *       unless the element is absent, which the model says it is not.
 *  modes (freq_hz, zeta; n = the model's degrees of freedom, ascending frequency as
 *  vibid_model_modal returns them):
 *   VIBID_IMPLAUSIBLE_NONFINITE     f_i or zeta_i is NaN or Inf (e.g. the modal
 *                                   computation failed on a singular mass matrix).
 *   VIBID_IMPLAUSIBLE_FREQ_ZERO     f_i <= 0 Hz: vibid_model_modal reports a negative
 *                                   stiffness direction (a real eigenvalue pair of
 *                                   opposite sign) or a rigid-body mode as f = 0, zeta = 1.
 *   VIBID_IMPLAUSIBLE_FREQ_NYQUIST  f_i >= 1 / (2 sample_time) (at or above Nyquist: a
 *                                   mode that sampled data cannot show). Skipped when
 *                                   sample_time = 0.
 *   VIBID_IMPLAUSIBLE_ZETA_NEGATIVE zeta_i < -VIBID_PLAUSIBILITY_ZETA_TOL (1e-6): an
 *                                   unstable mode (negative damping); a passive stand has
 *                                   none. The margin covers the eigenvalue solver's
 *                                   rounding: an undamped mode (D = 0) comes out at
 *                                   |zeta| ~ 1e-14 (example 1 with d = 0: -3.6e-15).
 *   VIBID_IMPLAUSIBLE_OVERDAMPED    zeta_i >= 1 for a mode whose reference counterpart
 *                                   (mode i of the reference, matched by order as in
 *                                   vibid_model_modal's standard errors) is underdamped
 *                                   (reference zeta < 1). Needs a reference
 *                                   (vibid_plausibility_ref_init); skipped when the
 *                                   reference could not be computed (ref->zeta_rule == 0,
 *                                   the reason in ref->zeta_rule_off) or ref is NULL.
 *
 * Real time: vibid_plausibility_check allocates nothing and never throws (argument errors
 * are formatted into the fixed last-error buffer); its cost is O(p + n) plus formatting
 * `why`. vibid_plausibility_ref_init allocates (it runs vibid_model_modal once): call it
 * once, before the loop. Both are thread-safe for different ref objects; the model is
 * only read.
 */
#ifndef VIBID_PLAUSIBILITY_H
#define VIBID_PLAUSIBILITY_H

#include <vibid/common.h>
#include <vibid/model.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Rule bits (summary, per parameter, per mode). */
#define VIBID_IMPLAUSIBLE_NONFINITE 0x01u
#define VIBID_IMPLAUSIBLE_MASS 0x02u
#define VIBID_IMPLAUSIBLE_DAMPING 0x04u
#define VIBID_IMPLAUSIBLE_STIFFNESS 0x08u
#define VIBID_IMPLAUSIBLE_FREQ_ZERO 0x10u
#define VIBID_IMPLAUSIBLE_FREQ_NYQUIST 0x20u
#define VIBID_IMPLAUSIBLE_ZETA_NEGATIVE 0x40u
#define VIBID_IMPLAUSIBLE_OVERDAMPED 0x80u

/* Rounding margin of the negative-damping-ratio rule (see above). */
#define VIBID_PLAUSIBILITY_ZETA_TOL 1e-6

/* Largest number of modes a reference holds (as vibid_modal's n limit). */
#define VIBID_PLAUSIBILITY_MAX_MODES 512

/* Reference for the damping-ratio rule: the modes of the model at reference parameter
 * values (normally the nominal ones), computed once. Caller-allocated (about 8 KiB, no
 * pointers inside: it may be copied, embedded and shared read-only between threads);
 * filled only by vibid_plausibility_ref_init. */
typedef struct vibid_plausibility_ref {
    size_t n_params;         /* p of the model it was made for */
    size_t n_modes;          /* n of the model it was made for */
    int zeta_rule;           /* non-zero: the OVERDAMPED rule is applied */
    char zeta_rule_off[256]; /* zeta_rule == 0: why (e.g. "the nominal value of c1 is not
                                given (0)"); "" otherwise */
    double freq_hz[VIBID_PLAUSIBILITY_MAX_MODES]; /* reference modes (Hz), n_modes used;
                                                     NaN when zeta_rule == 0 */
    double zeta[VIBID_PLAUSIBILITY_MAX_MODES];    /* reference damping ratios */
} vibid_plausibility_ref;

/* Computes the reference from a finalized model.
 *   theta_ref  p reference values (model units), or NULL = the nominal values
 *              (vibid_model_nominal).
 * The damping-ratio rule needs a physically complete reference: if a sign-constrained
 * unknown (see above: a mass, damper or spring; a diagonal entry of M, D, C) has a
 * reference value <= 0 ("0 = not given" for a nominal value), or a value is not finite,
 * or the reference has more than VIBID_PLAUSIBILITY_MAX_MODES modes, or its modal
 * computation fails, the function still succeeds, sets ref->zeta_rule = 0 and says why in
 * ref->zeta_rule_off; the other rules do not need the reference.
 * Errors: VIBID_E_NULL_ARGUMENT (model or ref), VIBID_E_STATE (model not finalized); ref
 * is then left unchanged. Allocates (not for real-time use). */
VIBID_API vibid_status vibid_plausibility_ref_init(const vibid_model *model, const double *theta_ref,
                                                   vibid_plausibility_ref *ref);

/* Checks one estimate.
 *   model        finalized model (only read).
 *   sample_time  h in s, > 0 and finite: the Nyquist rule uses f_a / 2 = 1 / (2 h);
 *                0 skips that rule.
 *   theta        p estimated parameters (model units), or NULL: no parameter rules.
 *   freq_hz, zeta  n_modes natural frequencies (Hz) and damping ratios from
 *                vibid_model_modal at theta; n_modes is 0 (no mode rules, both may be
 *                NULL) or the model's number of degrees of freedom (both required).
 *   ref          from vibid_plausibility_ref_init for this model, or NULL (the
 *                damping-ratio rule is skipped).
 *   flags_out    required: the OR of every bit found, 0 = plausible.
 *   param_flags  p entries, the bits of each parameter (0 = fine); may be NULL.
 *   mode_flags   n_modes entries, the bits of each mode; may be NULL.
 *   why, why_cap optional (NULL / 0): a sentence naming every finding with its value,
 *                clauses separated by "; ", e.g.
 *                  "c2 = -18981 N/m <= 0 (stiffness must be positive); mode 1 at 0 Hz <= 0"
 *                "" when plausible; cut at why_cap - 1 characters (always terminated).
 *                Numbers are printed with 6 significant digits and SI units as in model.h.
 * Errors (outputs untouched, vibid_last_error names the argument):
 *   VIBID_E_NULL_ARGUMENT model or flags_out NULL, or freq_hz/zeta NULL with n_modes > 0;
 *   VIBID_E_STATE model not finalized;
 *   VIBID_E_DIMENSION n_modes neither 0 nor n, or ref made for another model (its
 *                     n_params/n_modes differ; a zeroed, never initialized ref does too);
 *   VIBID_E_OUT_OF_RANGE sample_time < 0 or not finite.
 * A finding is not an error: the call returns VIBID_OK with the bits set. */
VIBID_API vibid_status vibid_plausibility_check(const vibid_model *model, double sample_time, const double *theta,
                                                const double *freq_hz, const double *zeta, size_t n_modes,
                                                const vibid_plausibility_ref *ref, unsigned *flags_out,
                                                unsigned *param_flags, unsigned *mode_flags, char *why,
                                                size_t why_cap);

#ifdef __cplusplus
}
#endif
#endif
