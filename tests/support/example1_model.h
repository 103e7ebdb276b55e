/* example1_model.h: the paper's example 1 as a lumped network, for the tests (C and C++,
 * header only: the rt_* programs link the library variant vibid_rtcheck, the others the
 * shared library, and both include this). m1 = 10 kg, m2 = 20 kg known; c1 (m1-m2),
 * d (m1-m2), c2 (m2-base) unknown with nominal values 2.5e5 N/m, 300 N s/m, 1.5e6 N/m
 * (c1's nominal value 0 = not given when no_nominal_c1); the displacements of m1, m2 and
 * the base measured. Include after cmocka.h. */
#ifndef VIBID_TEST_EXAMPLE1_MODEL_H
#define VIBID_TEST_EXAMPLE1_MODEL_H

#include <stddef.h>

#include <vibid/model.h>

static inline vibid_model *example1_model(int no_nominal_c1)
{
    vibid_model *m = vibid_model_create();
    assert_non_null(m);
    size_t n1 = 0, n2 = 0;
    assert_int_equal(vibid_model_add_node(m, "m1", 10.0, 0, &n1), VIBID_OK);
    assert_int_equal(vibid_model_add_node(m, "m2", 20.0, 0, &n2), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "c1", VIBID_ELEMENT_SPRING, n1, n2, no_nominal_c1 ? 0.0 : 2.5e5, 1),
                     VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "d", VIBID_ELEMENT_DAMPER, n1, n2, 300.0, 1), VIBID_OK);
    assert_int_equal(vibid_model_add_element(m, "c2", VIBID_ELEMENT_SPRING, n2, VIBID_BASE, 1.5e6, 1), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m, n1, VIBID_MEASURE_DISPLACEMENT), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m, n2, VIBID_MEASURE_DISPLACEMENT), VIBID_OK);
    assert_int_equal(vibid_model_set_measured(m, VIBID_BASE, VIBID_MEASURE_DISPLACEMENT), VIBID_OK);
    assert_int_equal(vibid_model_finalize(m), VIBID_OK);
    return m;
}

#endif
