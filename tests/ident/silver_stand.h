/* tests/ident/silver_stand.h: 1 DOF, hardening cubic spring, unknown input gain, the issue's
 * real capture in kind: about 9 samples per period of the resonance at 68 Hz (fs 610 Hz),
 * force smooth, displacement measured. Shared by ident.output_error (test_output_error.c) and
 * ident.constant_terms (test_constant_terms.c). A libconfig stand file with a simulation
 * section (docs/stand-file.md, docs/sim.md). */
#ifndef IDENT_SILVER_STAND_H
#define IDENT_SILVER_STAND_H

static const char *silver_stand =
    "stand = { name = \"silver\"; sample_rate = 610.35;\n"
    "  nodes = ( { name = \"m\"; mass = 1.0; measure = { displacement = \"x\"; }; } );\n"
    "  elements = ( { name = \"k\"; kind = \"spring\"; between = [\"m\", \"ground\"]; unknown = true; true_value = 1.8e5; },\n"
    "               { name = \"d\"; kind = \"damper\"; between = [\"m\", \"ground\"]; unknown = true; true_value = 30.0; },\n"
    "               { name = \"eps\"; kind = \"cubic_spring\"; between = [\"m\", \"ground\"]; unknown = true; true_value = 2.0e10; } );\n"
    "  inputs = ( { name = \"u\"; node = \"m\"; gain = 1.0; unknown = true; true_value = 1.0; channel = \"F\"; } ); };\n"
    "simulation = { seed = 9; excitation = ( { target = \"u\"; kind = \"noise\"; amplitude = 20.0; f_low = 5.0; f_high = 150.0; } ); };\n";

#endif
