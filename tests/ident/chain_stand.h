/* tests/ident/chain_stand.h: the 3-DOF chain of the issue (held force on m3, x and a
 * measured on every node, modes 11.5 / 26.4 / 37.5 Hz), without nominal values: its
 * true values are for the simulation only, so the automatic estimator runs the pre-filter
 * pilot. Shared by ident.default (test_default.c) and bench/bench_ident.c, so that the
 * benchmark times the pilot on the stand the tests measure. A libconfig stand file with
 * a simulation section (docs/stand-file.md, docs/sim.md). */
#ifndef IDENT_CHAIN_STAND_H
#define IDENT_CHAIN_STAND_H

static const char *chain_stand =
    "stand = { name = \"chain3\"; sample_rate = 2000.0;\n"
    "  nodes = ( { name = \"m1\"; mass = 2.0; measure = { displacement = \"x1\"; acceleration = \"a1\"; }; },\n"
    "            { name = \"m2\"; mass = 1.5; measure = { displacement = \"x2\"; acceleration = \"a2\"; }; },\n"
    "            { name = \"m3\"; mass = 1.0; measure = { displacement = \"x3\"; acceleration = \"a3\"; }; } );\n"
    "  elements = ( { name = \"k1\"; kind = \"spring\"; between = [\"m1\", \"ground\"]; unknown = true; true_value = 4.0e4; },\n"
    "               { name = \"d1\"; kind = \"damper\"; between = [\"m1\", \"ground\"]; unknown = true; true_value = 20.0; },\n"
    "               { name = \"k2\"; kind = \"spring\"; between = [\"m2\", \"m1\"]; unknown = true; true_value = 3.0e4; },\n"
    "               { name = \"d2\"; kind = \"damper\"; between = [\"m2\", \"m1\"]; unknown = true; true_value = 15.0; },\n"
    "               { name = \"k3\"; kind = \"spring\"; between = [\"m3\", \"m2\"]; unknown = true; true_value = 2.0e4; },\n"
    "               { name = \"d3\"; kind = \"damper\"; between = [\"m3\", \"m2\"]; unknown = true; true_value = 10.0; } );\n"
    "  inputs = ( { name = \"f\"; node = \"m3\"; gain = 1.0; channel = \"F\"; hold = \"zoh\"; } ); };\n"
    "simulation = { seed = 3; excitation = ( { target = \"f\"; kind = \"noise\"; amplitude = 20.0; f_high = 150.0; } ); };\n";

#endif
