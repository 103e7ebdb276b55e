/* tests/ident/cubic_stand.h: 1 DOF with a strong hardening cubic spring (cubic force = linear
 * force at 1 mm), force smooth, only the displacement measured, no nominal values. Shared by
 * ident.default (test_default.c) and ident.output_error (test_output_error.c). A libconfig
 * stand file with a simulation section (docs/stand-file.md, docs/sim.md). */
#ifndef IDENT_CUBIC_STAND_H
#define IDENT_CUBIC_STAND_H

static const char *cubic_stand =
    "stand = { name = \"cubic1\"; sample_rate = 2000.0;\n"
    "  nodes = ( { name = \"m\"; mass = 1.0; measure = { displacement = \"x\"; }; } );\n"
    "  elements = ( { name = \"k\"; kind = \"spring\"; between = [\"m\", \"ground\"]; unknown = true; true_value = 1.0e4; },\n"
    "               { name = \"d\"; kind = \"damper\"; between = [\"m\", \"ground\"]; unknown = true; true_value = 5.0; },\n"
    "               { name = \"eps\"; kind = \"cubic_spring\"; between = [\"m\", \"ground\"]; unknown = true; true_value = 1.0e10; } );\n"
    "  inputs = ( { name = \"f\"; node = \"m\"; gain = 1.0; channel = \"F\"; } ); };\n"
    "simulation = { seed = 4; excitation = ( { target = \"f\"; kind = \"noise\"; amplitude = 15.0; f_low = 2.0; f_high = 80.0; } ); };\n";

#endif
