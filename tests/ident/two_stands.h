/* tests/ident/two_stands.h: two stands of the identification tests, without nominal values
 * (their true values are for the simulation only), so the automatic estimator runs its
 * pre-filter pilot. Shared by ident.default (test_default.c) and ident.twin (test_twin.c).
 * Libconfig stand files with a simulation section (docs/stand-file.md, docs/sim.md). */
#ifndef IDENT_TWO_STANDS_H
#define IDENT_TWO_STANDS_H

/* 2 DOF on a moving base whose displacement is held between samples, a damper to the base
 * (its impulses are simulated, docs/sim.md), x1, x2 and s measured. */
static const char *base_stand =
    "stand = { name = \"base2\"; sample_rate = 2000.0;\n"
    "  nodes = ( { name = \"m1\"; mass = 1.5; measure = { displacement = \"x1\"; }; },\n"
    "            { name = \"m2\"; mass = 3.0; measure = { displacement = \"x2\"; }; } );\n"
    "  base = { hold = \"zoh\"; measure = { displacement = \"s\"; }; };\n"
    "  elements = ( { name = \"c1\"; kind = \"spring\"; between = [\"m1\", \"m2\"]; unknown = true; true_value = 6.0e4; },\n"
    "               { name = \"d1\"; kind = \"damper\"; between = [\"m1\", \"m2\"]; unknown = true; true_value = 15.0; },\n"
    "               { name = \"c2\"; kind = \"spring\"; between = [\"m2\", \"base\"]; unknown = true; true_value = 1.2e5; },\n"
    "               { name = \"d2\"; kind = \"damper\"; between = [\"m2\", \"base\"]; unknown = true; true_value = 30.0; } ); };\n"
    "simulation = { seed = 5; excitation = ( { target = \"base\"; kind = \"noise\"; amplitude = 1.0e-4; f_high = 150.0; } ); };\n";

/* 1 DOF, mode at 120 Hz (k = m (2 pi 120)^2), 2 % damping, smooth force to 300 Hz. */
static const char *high_stand =
    "stand = { name = \"high1\"; sample_rate = 2000.0;\n"
    "  nodes = ( { name = \"m\"; mass = 1.0; measure = { displacement = \"x\"; }; } );\n"
    "  elements = ( { name = \"k\"; kind = \"spring\"; between = [\"m\", \"ground\"]; unknown = true; true_value = 5.6849e5; },\n"
    "               { name = \"d\"; kind = \"damper\"; between = [\"m\", \"ground\"]; unknown = true; true_value = 30.0; } );\n"
    "  inputs = ( { name = \"f\"; node = \"m\"; gain = 1.0; channel = \"F\"; } ); };\n"
    "simulation = { seed = 6; excitation = ( { target = \"f\"; kind = \"noise\"; amplitude = 50.0; f_high = 300.0; } ); };\n";

#endif
