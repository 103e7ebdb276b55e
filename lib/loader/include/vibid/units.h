/* vibid/units.h: the physical units a stand file or a channel map may name, and their
 * factors to SI. One table for every program (stand loader, vibidd's channel check,
 * vibid-sim), so that "mm/s" means the same everywhere.
 *
 * Accepted spellings (case-sensitive, as printed on data sheets):
 *   length        m, cm, mm, um (also µm, μm), nm, in
 *   velocity      <length>/s, e.g. m/s, mm/s, in/s
 *   acceleration  <length>/s^2 (also <length>/s2, <length>/s²), g (standard gravity,
 *                 9.80665 m/s^2)
 *   force         N, mN, kN, daN, lbf
 */
#ifndef VIBID_UNITS_H
#define VIBID_UNITS_H

#ifdef __cplusplus
extern "C" {
#endif

typedef enum vibid_unit_dim {
    VIBID_DIM_LENGTH = 0,       /* SI: m */
    VIBID_DIM_VELOCITY = 1,     /* SI: m/s */
    VIBID_DIM_ACCELERATION = 2, /* SI: m/s^2 */
    VIBID_DIM_FORCE = 3         /* SI: N */
} vibid_unit_dim;

/* Sets *factor so that (value in SI) = *factor * (value in `unit`) and returns 0; returns
 * -1 (and leaves *factor alone) when `unit` is NULL, empty or not a unit of `dim`. */
int vibid_unit_si_factor(vibid_unit_dim dim, const char *unit, double *factor);

/* "m, cm, mm, ..." : the accepted spellings of dim, for error messages (static). */
const char *vibid_unit_names(vibid_unit_dim dim);

/* "length", "velocity", "acceleration", "force" (static). */
const char *vibid_unit_dim_name(vibid_unit_dim dim);

#ifdef __cplusplus
}
#endif
#endif
