/* Unit tests: refine.c (render-and-compare refinement; the confidence rules: test_confidence.c).
 * Frames come from synth_sphere.h, a small renderer written from
 * docs/conventions.md, not from refine.c's own geometry. training/refine.py is checked against the same
 * behaviour in tests/training/test_refine.py. */
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

static void refines_pose_and_circle(void **state)
{
    const synth_fixture *f = *state;
    const uint8_t *tex = f->tex;
    const rf_texture *t = f->t;
    rf_work *w = f->w;
    char err[256];
    const double poses[2][3] = {{6.0, -11.0, 18.5}, {-27.0, 24.0, -4.0}};
    for (int k = 0; k < 2; k++) {
        double R[3][3], R0[3][3], Rp[3][3];
        sp_euler_to_matrix(poses[k], R);
        double cx = 327.3 + 5 * k, cy = 248.6;
        uint8_t *img = render(tex, R, cx, cy);
        rf_image fi = {img, FW, FH, 3, FW * 3};
        /* start half a degree off (the network's typical error), the circle
         * 1.5 px and 1 % off */
        double off[3] = {poses[k][0] + 0.4, poses[k][1] - 0.35, poses[k][2] + 0.3};
        sp_euler_to_matrix(off, R0);
        rf_out o;
        double r = r_true();
        assert_int_equal(
            rf_refine(t, w, &fi, cx + 1.2, cy - 0.9, r * 1.01, R0, 0, 1, &o, err, sizeof err), 0);
        double g = geodesic_deg(o.R, R);
        printf("  pose %d: %.4f deg off, centre %+.3f %+.3f px, radius %+.3f px, residual %.4f, %d "
               "steps\n",
               k, g, o.cx - cx, o.cy - cy, o.r - r, o.residual, o.iterations);
        assert_true(g < 0.1); /* the target, as a mean per axis: 0.1 deg */
        assert_true(fabs(o.cx - cx) < 0.25 && fabs(o.cy - cy) < 0.25 && fabs(o.r - r) < 0.25);
        assert_true(o.residual < 0.02);
        /* the same with the focal length known */
        assert_int_equal(
            rf_refine(t, w, &fi, cx + 1.2, cy - 0.9, r * 1.01, R0, F_PX, 1, &o, err, sizeof err),
            0);
        assert_true(geodesic_deg(o.R, R) < 0.1);
        /* steps = 0: R0 kept, the residual at it is larger */
        rf_out o0;
        assert_int_equal(
            rf_refine(t, w, &fi, cx + 1.2, cy - 0.9, r * 1.01, R0, 0, 0, &o0, err, sizeof err), 0);
        memcpy(Rp, o0.R, sizeof Rp);
        assert_true(geodesic_deg(Rp, R0) == 0 && o0.iterations == 0);
        assert_true(o0.residual > 2 * o.residual);
        free(img);
    }
    /* another texture at the same pose: the residual says so */
    {
        uint8_t *other = make_texture(99);
        double R[3][3], e[3] = {5, 10, -15};
        sp_euler_to_matrix(e, R);
        uint8_t *img = render(other, R, 320, 256);
        rf_image fi = {img, FW, FH, 3, FW * 3};
        rf_out o;
        assert_int_equal(rf_refine(t, w, &fi, 320, 256, r_true(), R, 0, 1, &o, err, sizeof err), 0);
        printf("  other texture: residual %.3f\n", o.residual);
        assert_true(o.residual > 0.3);
        free(img);
        free(other);
    }
}

static void refuses_bad_input(void **state)
{
    (void)state;
    char err[256];
    uint8_t px[16 * 16 * 3] = {0};
    rf_image bad = {px, 16, 16, 3, 48};
    assert_null(rf_texture_new(&bad, err));
    assert_non_null(strstr(err, "width = 2 x height"));
    uint8_t *big = calloc(2 * 600 * 600 * 3, 1);
    rf_image odd = {big, 1200, 600, 3, 3600};
    assert_null(rf_texture_new(&odd, err));
    assert_non_null(strstr(err, "multiple of 256"));
    free(big);
    uint8_t *tex = make_texture(1);
    rf_image ti = {tex, TW, TH, 3, TW * 3};
    rf_texture *t = rf_texture_new(&ti, err);
    rf_work *w = rf_work_new();
    double R[3][3], e[3] = {0, 0, 0};
    rf_out o;
    sp_euler_to_matrix(e, R);
    uint8_t frame[64 * 48 * 3] = {0};
    rf_image fi = {frame, 64, 48, 3, 64 * 3};
    assert_int_equal(rf_refine(t, w, &fi, 500, 500, 30, R, 0, 1, &o, err, sizeof err),
                     -1); /* off the frame */
    assert_int_equal(rf_refine(t, w, &fi, 32, 24, 3, R, 0, 1, &o, err, sizeof err),
                     -1); /* too small */
    assert_int_equal(rf_refine(t, w, &fi, NAN, 24, 20, R, 0, 1, &o, err, sizeof err), -1);
    rf_work_free(w);
    rf_texture_free(t);
    free(tex);
}

static void base64(void **state)
{
    (void)state;
    unsigned char *out;
    size_t n;
    assert_int_equal(rf_base64_decode("aGVsbG8gd29ybGQ=", &out, &n), 0);
    assert_int_equal(n, 11);
    assert_memory_equal(out, "hello world", 11);
    free(out);
    assert_int_equal(rf_base64_decode("", &out, &n), 0);
    assert_int_equal(n, 0);
    free(out);
    assert_int_equal(rf_base64_decode("aGVsbG8*", &out, &n), -1);
    assert_int_equal(rf_base64_decode("aGVsbG8", &out, &n), -1);  /* not a multiple of 4 */
    assert_int_equal(rf_base64_decode("aG=sbG8=", &out, &n), -1); /* data after padding */
}

static void euler_roundtrip(void **state)
{
    (void)state;
    /* (12, -27, 6) of tests/data/conventions_vectors.json: R[2][0] = sin 27 deg */
    double e[3] = {12, -27, 6}, R[3][3], back[3];
    sp_euler_to_matrix(e, R);
    assert_true(fabs(R[2][0] - sin(27 * M_PI / 180)) < 1e-12);
    rf_matrix_to_euler(R, back);
    for (int i = 0; i < 3; i++) assert_true(fabs(back[i] - e[i]) < 1e-9);
}

/* One frame in every layout the refinement reads: BGRA gives the BGR
 * answer to the bit, a gray frame the same answer as one channel or as three
 * equal ones (the texture seen as its luma), close to the truth; and a sphere
 * cut by the frame's edge (a partial set of samples) still refines. */
static void frame_layouts_agree(void **state)
{
    const synth_fixture *f = *state;
    const uint8_t *tex = f->tex;
    const rf_texture *t = f->t;
    rf_work *w = f->w;
    char err[256];
    double R[3][3], R0[3][3], e[3] = {-12.0, 7.5, 21.0}, e0[3] = {-11.6, 7.2, 21.3};
    sp_euler_to_matrix(e, R);
    sp_euler_to_matrix(e0, R0);
    double cx = 311.4, cy = 262.2, r = r_true();
    uint8_t *bgr = render(tex, R, cx, cy);
    uint8_t *bgra = malloc((size_t)FW * FH * 4), *g3 = malloc((size_t)FW * FH * 3),
            *g1 = malloc((size_t)FW * FH);
    for (size_t i = 0; i < (size_t)FW * FH; i++) {
        const uint8_t *p = bgr + 3 * i;
        memcpy(bgra + 4 * i, p, 3);
        bgra[4 * i + 3] = 255;
        g1[i] = (uint8_t)((p[0] * 29 + p[1] * 150 + p[2] * 77 + 128) >> 8);
        memset(g3 + 3 * i, g1[i], 3);
    }
    rf_image f_bgr = {bgr, FW, FH, 3, FW * 3}, f_bgra = {bgra, FW, FH, 4, FW * 4};
    rf_image f_g3 = {g3, FW, FH, 3, FW * 3}, f_g1 = {g1, FW, FH, 1, FW};
    rf_out a, b, c, d;
    assert_int_equal(
        rf_refine(t, w, &f_bgr, cx + 0.8, cy - 0.6, r, R0, F_PX, 1, &a, err, sizeof err), 0);
    assert_int_equal(
        rf_refine(t, w, &f_bgra, cx + 0.8, cy - 0.6, r, R0, F_PX, 1, &b, err, sizeof err), 0);
    assert_memory_equal(a.R, b.R, sizeof a.R);
    assert_true(a.residual == b.residual && a.colour == b.colour);
    assert_true(geodesic_deg(a.R, R) < 0.1 && !isnan(a.colour));
    assert_int_equal(
        rf_refine(t, w, &f_g3, cx + 0.8, cy - 0.6, r, R0, F_PX, 1, &c, err, sizeof err), 0);
    assert_int_equal(
        rf_refine(t, w, &f_g1, cx + 0.8, cy - 0.6, r, R0, F_PX, 1, &d, err, sizeof err), 0);
    assert_memory_equal(c.R, d.R, sizeof c.R);
    assert_true(c.residual == d.residual && isnan(c.colour) && isnan(d.colour));
    printf("  gray: %.4f deg off, residual %.4f\n", geodesic_deg(c.R, R), c.residual);
    assert_true(geodesic_deg(c.R, R) < 0.2 && c.residual < 0.05);
    free(bgr);
    /* the sphere's right third outside the frame */
    double ex = FW - 0.6 * r;
    bgr = render(tex, R, ex, cy);
    f_bgr.data = bgr;
    assert_int_equal(
        rf_refine(t, w, &f_bgr, ex + 0.8, cy - 0.6, r, R0, F_PX, 1, &a, err, sizeof err), 0);
    printf("  cut by the edge: %.4f deg off, residual %.4f\n", geodesic_deg(a.R, R), a.residual);
    assert_true(geodesic_deg(a.R, R) < 0.2);
    free(bgr);
    free(bgra);
    free(g3);
    free(g1);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(refines_pose_and_circle, synth_setup, synth_teardown),
        cmocka_unit_test_setup_teardown(frame_layouts_agree, synth_setup, synth_teardown),
        cmocka_unit_test(refuses_bad_input),
        cmocka_unit_test(base64),
        cmocka_unit_test(euler_roundtrip),
    };
    return cmocka_run_group_tests_name("refine", tests, NULL, NULL);
}
