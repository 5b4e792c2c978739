/* Unit test: the versions of refine.c's per-pixel loops (refine.h
 * RF_VERSION_LIST: portable, x86-64 baseline, AVX2, AVX-512;
 * rf_set_version) refine the same frames to the same answers: the portable,
 * baseline and AVX2 versions to the same bits (they fuse no multiply-add),
 * the AVX-512 version within rounding (docs/refine.md). Each version runs
 * where the processor has it (the portable one everywhere: on x86-64 it is
 * the code aarch64 runs); the texture at 1024, 2048 and 4096 wide, so that
 * both of its layouts (pairs and tiles) are read. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "poseinfer.h"
#include "refine.h"

#include "synth_sphere.h"

#define NTEX    3
/* three colour frames, one gray; the third colour frame's centre (where the
 * padding of the sample arrays samples the texture) on a bar's edge, where
 * the texture has a gradient at every level: the padding must not count */
#define NFRAMES 4

/* The texture scaled to w x w/2 (nearest texel). */
static uint8_t *scaled(const uint8_t *t, int w)
{
    int h = w / 2;
    uint8_t *o = malloc((size_t)w * h * 3);
    if (!o) return NULL;
    for (int j = 0; j < h; j++)
        for (int i = 0; i < w; i++)
            memcpy(o + ((size_t)j * w + i) * 3,
                   t + ((size_t)(j * TH / h) * TW + (size_t)i * TW / w) * 3, 3);
    return o;
}

/* Every answer of one version: per texture and frame, the checked
 * refinement's pose, circle, residual and colour ratio. */
typedef struct answers {
    rf_out o[NTEX][NFRAMES];
    double moved[NTEX][NFRAMES];
} answers;

static void run_version(const rf_texture *const t[NTEX], rf_work *w, uint8_t *const frames[NFRAMES],
                        const double poses[NFRAMES][3], answers *a)
{
    char err[256];
    for (int x = 0; x < NTEX; x++)
        for (int k = 0; k < NFRAMES; k++) {
            rf_image fi = {frames[k], FW, FH, 3, FW * 3};
            /* about a degree off: a gray frame takes more than one pass */
            double off[3] = {poses[k][0] + 0.9, poses[k][1] - 0.7, poses[k][2] + 0.6}, R0[3][3];
            sp_euler_to_matrix(off, R0);
            memset(&a->o[x][k], 0, sizeof a->o[x][k]);
            assert_int_equal(rf_refine_checked(t[x], w, &fi, 327.3 + 1.5, 248.6 - 1.1,
                                               r_true() * 1.02, R0, F_PX, 1, 0.5, &a->o[x][k],
                                               &a->moved[x][k], err, sizeof err),
                             0);
        }
}

static int same_bits(const answers *a, const answers *b)
{
    for (int x = 0; x < NTEX; x++)
        for (int k = 0; k < NFRAMES; k++) {
            const rf_out *p = &a->o[x][k], *q = &b->o[x][k];
            double u[] = {p->euler[0], p->euler[1], p->euler[2], p->cx,         p->cy,
                          p->r,        p->residual, p->colour,   a->moved[x][k]};
            double v[] = {q->euler[0], q->euler[1], q->euler[2], q->cx,         q->cy,
                          q->r,        q->residual, q->colour,   b->moved[x][k]};
            if (memcmp(u, v, sizeof u) || p->iterations != q->iterations) return 0;
        }
    return 1;
}

static void versions_agree(void **state)
{
    (void)state;
    const double poses[NFRAMES][3] = {
        {6.0, -11.0, 18.5}, {-27.0, 24.0, -4.0}, {0.0, -14.06, 10.0}, {12.0, 3.0, -20.0}};
    const int widths[NTEX] = {1024, 2048, 4096};
    uint8_t *tex = make_texture(7), *frames[NFRAMES];
    rf_texture *t[NTEX];
    char err[RF_TEXTURE_ERR_LEN];
    assert_non_null(tex);
    for (int x = 0; x < NTEX; x++) {
        uint8_t *tx = widths[x] == TW ? tex : scaled(tex, widths[x]);
        assert_non_null(tx);
        rf_image ti = {tx, widths[x], widths[x] / 2, 3, widths[x] * 3};
        t[x] = rf_texture_new(&ti, err);
        assert_non_null(t[x]);
        if (tx != tex) free(tx);
    }
    for (int k = 0; k < NFRAMES; k++) {
        double R[3][3];
        sp_euler_to_matrix(poses[k], R);
        frames[k] = render(tex, R, 327.3, 248.6);
        if (k == NFRAMES - 1) /* a mono camera: three equal channels */
            for (size_t p = 0; p < (size_t)FW * FH; p++) {
                uint8_t *q = frames[k] + 3 * p;
                q[0] = q[1] = q[2] = (uint8_t)((q[0] * 29 + q[1] * 150 + q[2] * 77) >> 8);
            }
    }
    rf_work *w = rf_work_new();
    assert_non_null(w);
    int best = rf_set_version(-1);
    assert_true(best >= 0 && best < RF_V_COUNT);
    assert_int_equal(rf_set_version(best + 1), best); /* no more than the processor has */
    static answers a[RF_V_COUNT];
#define NAMED(id, name) "refinement " name,
    static const char *const named[RF_V_COUNT] = {RF_VERSION_LIST(NAMED)};
#undef NAMED
    for (int v = 0; v <= best; v++) {
        assert_int_equal(rf_set_version(v), v);
        assert_int_equal(rf_version_in_use(), v);
        assert_non_null(strstr(pi_cpu_paths(), named[v])); /* what the bench reports */
        run_version((const rf_texture *const *)t, w, frames, poses, &a[v]);
    }
    rf_set_version(-1);
    printf("  versions run: %s .. %s\n", named[0], named[best]);
    /* the portable version (aarch64's, clang's) against the baseline, the
     * baseline against AVX2: the same bits */
    for (int v = RF_V_BASELINE; v <= best && v <= RF_V_AVX2; v++)
        assert_true(same_bits(&a[v], &a[v - 1]));
    if (best >= RF_V_AVX512) {
        /* rounding apart: the answers within a small part of what the
         * C-against-Python tests allow (0.005 deg) */
        double dmax = 0, cmax = 0, rmax = 0;
        for (int x = 0; x < NTEX; x++)
            for (int k = 0; k < NFRAMES; k++) {
                const rf_out *p = &a[RF_V_AVX512].o[x][k], *q = &a[RF_V_BASELINE].o[x][k];
                double d = geodesic_deg(p->R, q->R), c = fabs(p->cx - q->cx) + fabs(p->cy - q->cy);
                if (fabs(p->r - q->r) > c) c = fabs(p->r - q->r);
                dmax = d > dmax ? d : dmax;
                cmax = c > cmax ? c : cmax;
                double e = fabs(p->residual - q->residual);
                rmax = e > rmax ? e : rmax;
                assert_true(isnan(p->colour) == isnan(q->colour));
                if (!isnan(p->colour)) assert_true(fabs(p->colour - q->colour) < 1e-4);
            }
        printf("  AVX-512 against baseline: poses %.2g deg, circle %.2g px, residual %.2g\n", dmax,
               cmax, rmax);
        assert_true(dmax < 5e-4);
        assert_true(cmax < 5e-3);
        assert_true(rmax < 1e-5);
    }
    rf_work_free(w);
    for (int k = 0; k < NFRAMES; k++) free(frames[k]);
    for (int x = 0; x < NTEX; x++) rf_texture_free(t[x]);
    free(tex);
    if (best == 0) skip(); /* one version in this build: nothing was compared */
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(versions_agree),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
