/* Unit tests: confidence.c (the thresholds, the judgement, the convergence
 * check). Frames come from the small renderer of synth_sphere.h.
 * training/refine.py is held to the same rules in
 * tests/training/test_refine.py. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "confidence.h"
#include "refine.h"

#include "synth_sphere.h"

static void confidence_rules(void **state)
{
    (void)state;
    rf_conf c;
    char err[256], note[160];
    rf_conf_defaults(&c);
    assert_int_equal(rf_conf_parse(&c, "{\"residual_max\": 0.05}",
                                   "{\"x\": [-30, 30], \"y\": [-30, 30], \"z\": [-20, 40]}", err,
                                   sizeof err),
                     0);
    assert_true(c.residual_max == 0.05 && c.residual_max_unrefined == 0.05 &&
                c.range_margin_deg == 2.0);
    double in[3] = {10, -29, 41.9}, out[3] = {0, 45.04, 0}, zero[3] = {0, 0, 0};
    assert_int_equal(rf_judge(&c, 0.01, NAN, NAN, in, 1, note, sizeof note), 1);
    assert_string_equal(note, "");
    assert_int_equal(rf_judge(&c, 0.06, NAN, NAN, zero, 1, note, sizeof note), 0);
    assert_non_null(strstr(note, "poor alignment (residual 0.060 > 0.050)"));
    assert_int_equal(rf_judge(&c, 0.01, NAN, NAN, out, 1, note, sizeof note), 0);
    assert_string_equal(note, "outside the model's ranges (y = 45.0 not in [-30, 30])");
    assert_int_equal(rf_judge(&c, NAN, NAN, NAN, zero, 1, note, sizeof note), 0);
    assert_int_equal(rf_conf_parse(&c, "{\"residual_max\": 0.05, \"residual_max_unrefined\": 0.3}",
                                   NULL, err, sizeof err),
                     0);
    assert_int_equal(rf_judge(&c, 0.2, NAN, NAN, zero, 0, note, sizeof note), 1);
    /* the colour ratio: colour frames only (NaN: a gray frame, no check) */
    assert_true(c.colour_min == 0);
    assert_int_equal(rf_conf_parse(&c, "{\"colour_min\": 0.4}", NULL, err, sizeof err), 0);
    assert_int_equal(rf_judge(&c, 0.01, 0.9, NAN, zero, 1, note, sizeof note), 1);
    assert_int_equal(rf_judge(&c, 0.01, NAN, NAN, zero, 1, note, sizeof note), 1);
    assert_int_equal(rf_judge(&c, 0.01, 0.12, NAN, zero, 1, note, sizeof note), 0);
    assert_non_null(strstr(note, "colours do not match (colour ratio 0.12 < 0.40)"));
    assert_int_equal(rf_conf_parse(&c, "{\"residual_max\": 2}", NULL, err, sizeof err), -1);
    assert_non_null(strstr(err, "residual_max"));
    assert_int_equal(rf_conf_parse(&c, "[1]", NULL, err, sizeof err), -1);
    assert_int_equal(rf_conf_parse(&c, NULL, "{\"x\": [1]}", err, sizeof err), -1);
    assert_non_null(strstr(err, "spherepose.ranges"));

    /* the convergence check: a checked answer (moved not NaN) whose last pass
     * rotated it more than converge_max_deg is not confident */
    rf_conf_defaults(&c);
    assert_true(c.converge_max_deg == 0.3);
    assert_int_equal(rf_judge(&c, 0.01, 0.9, 0.29, zero, 1, note, sizeof note), 1);
    assert_int_equal(rf_judge(&c, 0.01, NAN, 0.31, zero, 1, note, sizeof note), 0);
    assert_non_null(strstr(note, "not converged (a further pass moved it 0.31 deg > 0.30)"));
    assert_int_equal(rf_conf_parse(&c, "{\"converge_max_deg\": 0.5}", NULL, err, sizeof err), 0);
    assert_int_equal(rf_judge(&c, 0.01, NAN, 0.45, zero, 1, note, sizeof note), 1);
    assert_int_equal(rf_conf_parse(&c, "{\"converge_max_deg\": -1}", NULL, err, sizeof err), -1);
    assert_non_null(strstr(err, "converge_max_deg"));
    /* a refined gray frame (colour NaN) has its own residual threshold when set */
    rf_conf_defaults(&c);
    assert_int_equal(rf_conf_parse(&c, "{\"residual_max\": 0.12, \"residual_max_gray\": 0.045}",
                                   NULL, err, sizeof err),
                     0);
    assert_int_equal(rf_judge(&c, 0.05, 0.9, NAN, zero, 1, note, sizeof note), 1);
    assert_int_equal(rf_judge(&c, 0.05, NAN, NAN, zero, 1, note, sizeof note), 0);
    assert_non_null(strstr(note, "poor alignment (residual 0.050 > 0.045)"));
    assert_int_equal(rf_judge(&c, 0.04, NAN, NAN, zero, 1, note, sizeof note), 1);
    assert_int_equal(rf_judge(&c, 0.05, NAN, NAN, zero, 0, note, sizeof note), 1); /* unrefined */
}

static void rotation_angle(void **state)
{
    (void)state;
    double A[3][3], B[3][3], e[3] = {3, -7, 12}, f[3] = {3, -7, 17};
    sp_euler_to_matrix(e, A);
    sp_euler_to_matrix(f, B);
    assert_true(fabs(rf_rotation_deg(A, B) - 5.0) < 1e-9); /* about the world's z */
    assert_true(rf_rotation_deg(A, A) < 1e-6);
}

/* The luma of a BGR frame as one channel (a mono camera). */
static uint8_t *to_gray(const uint8_t *img)
{
    uint8_t *g = malloc((size_t)FW * FH);
    for (size_t i = 0; i < (size_t)FW * FH; i++)
        g[i] = (uint8_t)(RF_LUMA_B * img[3 * i] + RF_LUMA_G * img[3 * i + 1] +
                         RF_LUMA_R * img[3 * i + 2] + 0.5);
    return g;
}

static void convergence_check(void **state)
{
    const synth_fixture *f = *state;
    const uint8_t *tex = f->tex;
    const rf_texture *t = f->t;
    rf_work *w = f->w;
    char err[256];
    double pose[3] = {8.0, -14.0, 21.0}, R[3][3], R0[3][3], moved, r = r_true();
    double cx = 322.4, cy = 251.3;
    sp_euler_to_matrix(pose, R);
    uint8_t *img = render(tex, R, cx, cy), *gray = to_gray(img);
    rf_image fi = {img, FW, FH, 3, FW * 3}, gi = {gray, FW, FH, 1, FW};
    rf_out o, o1;
    /* a colour frame from a start the first pass corrects a little: not
     * checked, the answer is the single pass's */
    double near[3] = {pose[0] + 0.4, pose[1] - 0.3, pose[2] + 0.2};
    sp_euler_to_matrix(near, R0);
    assert_int_equal(rf_refine_checked(t, w, &fi, cx + 0.5, cy - 0.4, r, R0, F_PX, 1, 0.3, &o,
                                       &moved, err, sizeof err),
                     0);
    assert_true(isnan(moved));
    assert_int_equal(rf_refine(t, w, &fi, cx + 0.5, cy - 0.4, r, R0, F_PX, 1, &o1, err, sizeof err),
                     0);
    assert_true(rf_rotation_deg(o.R, o1.R) == 0);
    /* steps = 0 (no refinement): never checked */
    assert_int_equal(
        rf_refine_checked(t, w, &gi, cx, cy, r, R0, F_PX, 0, 0.3, &o, &moved, err, sizeof err), 0);
    assert_true(isnan(moved));
    /* a gray frame from 7 degrees off (the shipped network's error on a mono
     * camera): checked, refined until a pass moves it at most 0.3 deg */
    double far[3] = {pose[0] - 4.0, pose[1] + 4.0, pose[2] - 4.0};
    sp_euler_to_matrix(far, R0);
    assert_int_equal(
        rf_refine_checked(t, w, &gi, cx, cy, r, R0, F_PX, 1, 0.3, &o, &moved, err, sizeof err), 0);
    printf("  gray, %.1f deg off: %.4f deg off after %d steps, last pass %.4f deg\n",
           rf_rotation_deg(R0, R), rf_rotation_deg(o.R, R), o.iterations, moved);
    assert_true(isnan(o.colour) && moved <= 0.3 && rf_rotation_deg(o.R, R) < 0.1);
    /* a colour frame whose circle was found 6 px off: checked */
    sp_euler_to_matrix(near, R0);
    assert_int_equal(rf_refine_checked(t, w, &fi, cx + 6.0, cy - 2.0, r * 1.03, R0, F_PX, 1, 0.3,
                                       &o, &moved, err, sizeof err),
                     0);
    printf("  circle 6 px off: %.4f deg off, last pass %.4f deg\n", rf_rotation_deg(o.R, R), moved);
    assert_false(isnan(moved));
    assert_true(moved <= 0.3 && rf_rotation_deg(o.R, R) < 0.1);
    free(gray);
    free(img);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(confidence_rules),
        cmocka_unit_test(rotation_angle),
        cmocka_unit_test_setup_teardown(convergence_check, synth_setup, synth_teardown),
    };
    return cmocka_run_group_tests_name("confidence", tests, NULL, NULL);
}
