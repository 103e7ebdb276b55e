/* bench_stands.h: the stands the per-sample benchmarks time (bench_ident.c,
 * bench_regressor.c), built through the C API: the paper's example 1 (2 DOF, 3 unknowns
 * c1, d, c2, displacements of both masses and the base measured: 3 channels) and a 3-DOF
 * chain on the ground with displacement and acceleration measured at every mass and a
 * held force on the last (6 unknowns, 7 channels). Finalized; the caller destroys them. */
#ifndef VIBID_BENCH_STANDS_H
#define VIBID_BENCH_STANDS_H

#include <vibid/model.h>

static inline vibid_model *bench_example1(void)
{
    vibid_model *m = vibid_model_create();
    size_t a, b;
    vibid_model_add_node(m, "m1", 10.0, 0, &a);
    vibid_model_add_node(m, "m2", 20.0, 0, &b);
    vibid_model_add_element(m, "c1", VIBID_ELEMENT_SPRING, a, b, 2.5e5, 1);
    vibid_model_add_element(m, "d", VIBID_ELEMENT_DAMPER, a, b, 300.0, 1);
    vibid_model_add_element(m, "c2", VIBID_ELEMENT_SPRING, b, VIBID_BASE, 1.5e6, 1);
    vibid_model_set_measured(m, a, VIBID_MEASURE_DISPLACEMENT);
    vibid_model_set_measured(m, b, VIBID_MEASURE_DISPLACEMENT);
    vibid_model_set_measured(m, VIBID_BASE, VIBID_MEASURE_DISPLACEMENT);
    vibid_model_finalize(m);
    return m;
}

static inline vibid_model *bench_chain3(void)
{
    vibid_model *m = vibid_model_create();
    size_t n[3];
    const char *names[3] = {"m1", "m2", "m3"};
    for (int i = 0; i < 3; i++) {
        vibid_model_add_node(m, names[i], 1.0 + 0.5 * i, 0, &n[i]);
        vibid_model_set_measured(m, n[i], VIBID_MEASURE_DISPLACEMENT | VIBID_MEASURE_ACCELERATION);
    }
    vibid_model_add_element(m, "k1", VIBID_ELEMENT_SPRING, n[0], VIBID_GROUND, 4e4, 1);
    vibid_model_add_element(m, "d1", VIBID_ELEMENT_DAMPER, n[0], VIBID_GROUND, 20, 1);
    vibid_model_add_element(m, "k2", VIBID_ELEMENT_SPRING, n[1], n[0], 3e4, 1);
    vibid_model_add_element(m, "d2", VIBID_ELEMENT_DAMPER, n[1], n[0], 15, 1);
    vibid_model_add_element(m, "k3", VIBID_ELEMENT_SPRING, n[2], n[1], 2e4, 1);
    vibid_model_add_element(m, "d3", VIBID_ELEMENT_DAMPER, n[2], n[1], 10, 1);
    size_t in;
    vibid_model_add_input(m, "f", n[2], 1.0, 0, &in);
    vibid_model_set_hold(m, in, VIBID_HOLD_ZOH);
    vibid_model_finalize(m);
    return m;
}

#endif
