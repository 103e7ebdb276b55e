/* units.c: the unit table of vibid/units.h. */
#include <vibid/units.h>

#include <stddef.h>
#include <string.h>

typedef struct unit_entry {
    const char *name;
    double si; /* SI value of one unit */
} unit_entry;

static const unit_entry lengths[] = {
    {"m", 1.0}, {"cm", 1e-2}, {"mm", 1e-3}, {"um", 1e-6}, {"\xc2\xb5m", 1e-6} /* µm, micro sign */,
    {"\xce\xbcm", 1e-6} /* μm, Greek mu */, {"nm", 1e-9}, {"in", 0.0254}, {NULL, 0}};

static const unit_entry forces[] = {{"N", 1.0},  {"mN", 1e-3},  {"kN", 1e3},
                                    {"daN", 10.0}, {"lbf", 4.4482216152605}, {NULL, 0}};

#define STANDARD_GRAVITY 9.80665 /* m/s^2, CGPM 1901 */

static int lookup(const unit_entry *t, const char *s, size_t n, double *si)
{
    for (; t->name; t++)
        if (strlen(t->name) == n && memcmp(t->name, s, n) == 0) {
            *si = t->si;
            return 0;
        }
    return -1;
}

int vibid_unit_si_factor(vibid_unit_dim dim, const char *unit, double *factor)
{
    if (!unit || !unit[0] || !factor)
        return -1;
    double si;
    size_t n = strlen(unit);
    switch (dim) {
    case VIBID_DIM_LENGTH:
        if (lookup(lengths, unit, n, &si))
            return -1;
        break;
    case VIBID_DIM_FORCE:
        if (lookup(forces, unit, n, &si))
            return -1;
        break;
    case VIBID_DIM_VELOCITY:
        if (n < 3 || strcmp(unit + n - 2, "/s") != 0 || lookup(lengths, unit, n - 2, &si))
            return -1;
        break;
    case VIBID_DIM_ACCELERATION: {
        if (strcmp(unit, "g") == 0) {
            si = STANDARD_GRAVITY;
            break;
        }
        static const char *const per_s2[] = {"/s^2", "/s2", "/s\xc2\xb2" /* /s² */};
        int ok = -1;
        for (size_t k = 0; k < 3 && ok; k++) {
            size_t m = strlen(per_s2[k]);
            if (n > m && strcmp(unit + n - m, per_s2[k]) == 0)
                ok = lookup(lengths, unit, n - m, &si);
        }
        if (ok)
            return -1;
        break;
    }
    default:
        return -1;
    }
    *factor = si;
    return 0;
}

const char *vibid_unit_names(vibid_unit_dim dim)
{
    switch (dim) {
    case VIBID_DIM_LENGTH: return "m, cm, mm, um, nm, in";
    case VIBID_DIM_VELOCITY: return "m/s, cm/s, mm/s, um/s, nm/s, in/s";
    case VIBID_DIM_ACCELERATION: return "m/s^2, cm/s^2, mm/s^2, um/s^2, in/s^2, g";
    case VIBID_DIM_FORCE: return "N, mN, kN, daN, lbf";
    }
    return "";
}

const char *vibid_unit_dim_name(vibid_unit_dim dim)
{
    static const char *const n[] = {"length", "velocity", "acceleration", "force"};
    return (unsigned)dim < 4 ? n[dim] : "unknown";
}
