/* synth_sphere.h -- a small renderer of the textured sphere for the unit
 * tests of refine.c and confidence.c, written from docs/conventions.md
 * (rays in millimetres, supersampled, nearest texel, a shading term), not
 * from refine.c's own geometry. Static functions: each test file that
 * includes it gets its own copy. Also the cmocka fixture the refinement
 * tests start from (synth_setup, synth_teardown). */
#ifndef SYNTH_SPHERE_H
#define SYNTH_SPHERE_H

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "refine.h"

#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif

#define TW 2048
#define TH 1024
#define FW 640
#define FH 512
static const double F_PX = 16.0 / 0.0096, D_MM = 250.0, R_MM = 20.0;

/* A block texture (BGR) from a fixed seed: random bars on white. */
static inline uint8_t *make_texture(unsigned seed)
{
    uint8_t *t = malloc((size_t)TW * TH * 3);
    static const uint8_t cols[3][3] = {{0, 0, 0}, {0, 128, 0}, {230, 40, 0}};
    memset(t, 255, (size_t)TW * TH * 3);
    for (int k = 0; k < 160; k++) {
        seed = seed * 1103515245u + 12345u;
        int x = (int)((seed >> 8) % TW), y = (int)((seed >> 4) % (TH - 80)) + 40;
        seed = seed * 1103515245u + 12345u;
        int horiz = (seed >> 9) & 1, len = 80 + (int)((seed >> 12) % 320),
            th = 24 + (int)((seed >> 20) % 20);
        const uint8_t *c = cols[(seed >> 24) % 3];
        for (int j = 0; j < (horiz ? th : len); j++)
            for (int i = 0; i < (horiz ? len : th); i++) {
                int yy = y + j, xx = (x + i) % TW;
                if (yy < 0 || yy >= TH) continue;
                memcpy(t + ((size_t)yy * TW + xx) * 3, c, 3);
            }
    }
    return t;
}

/* The sphere at pose R seen by the conventions' camera with its principal
 * point at (cx, cy), 3 x 3 samples per pixel. */
static inline uint8_t *render(const uint8_t *tex, const double R[3][3], double cx, double cy)
{
    uint8_t *img = malloc((size_t)FW * FH * 3);
    for (int v = 0; v < FH; v++)
        for (int u = 0; u < FW; u++) {
            double acc[3] = {0, 0, 0};
            for (int a = 0; a < 4; a++)
                for (int b = 0; b < 4; b++) {
                    double x = (u + (b + 0.5) / 4 - cx) / F_PX,
                           y = -(v + (a + 0.5) / 4 - cy) / F_PX;
                    double L = sqrt(x * x + y * y + 1), d[3] = {x / L, y / L, -1 / L};
                    double od = D_MM * d[2], disc = od * od - (D_MM * D_MM - R_MM * R_MM);
                    if (disc < 0) {
                        acc[0] += 64;
                        acc[1] += 64;
                        acc[2] += 70;
                        continue;
                    }
                    double t = -od - sqrt(disc),
                           n[3] = {t * d[0] / R_MM, t * d[1] / R_MM, (D_MM + t * d[2]) / R_MM};
                    double bd[3];
                    for (int i = 0; i < 3; i++)
                        bd[i] = R[0][i] * n[0] + R[1][i] * n[1] + R[2][i] * n[2];
                    double lon = atan2(bd[0], bd[2]), lat = asin(bd[1] > 1    ? 1
                                                                 : bd[1] < -1 ? -1
                                                                              : bd[1]);
                    int ti = ((int)floor((lon + M_PI) / (2 * M_PI) * TW) % TW + TW) % TW;
                    int tj = (int)floor((M_PI / 2 - lat) / M_PI * TH);
                    if (tj < 0) tj = 0;
                    if (tj >= TH) tj = TH - 1;
                    double s = 0.45 + 0.2 * n[1] + 0.4 * n[2];
                    for (int c = 0; c < 3; c++) acc[c] += tex[((size_t)tj * TW + ti) * 3 + c] * s;
                }
            for (int c = 0; c < 3; c++)
                img[((size_t)v * FW + u) * 3 + c] = (uint8_t)(acc[c] / 16 + 0.5);
        }
    return img;
}

static inline double geodesic_deg(const double A[3][3], const double B[3][3])
{
    double tr = 0;
    for (int i = 0; i < 3; i++)
        for (int k = 0; k < 3; k++) tr += A[k][i] * B[k][i];
    double c = (tr - 1) / 2;
    return acos(c > 1 ? 1 : c < -1 ? -1 : c) * 180 / M_PI;
}

static inline double r_true(void)
{
    return F_PX * R_MM / sqrt(D_MM * D_MM - R_MM * R_MM);
}

/* What a refinement test starts from: the texture of seed 7, its pyramid
 * and working memory. cmocka_unit_test_setup_teardown(test, synth_setup,
 * synth_teardown) hands it to the test as *state. */
typedef struct synth_fixture {
    uint8_t *tex;
    rf_texture *t;
    rf_work *w;
} synth_fixture;

static inline int synth_teardown(void **state)
{
    synth_fixture *f = *state;
    if (f) {
        rf_work_free(f->w);
        rf_texture_free(f->t);
        free(f->tex);
        free(f);
    }
    return 0;
}

static inline int synth_setup(void **state)
{
    char err[RF_TEXTURE_ERR_LEN];
    synth_fixture *f = calloc(1, sizeof *f);
    *state = f;
    if (!f) return -1;
    f->tex = make_texture(7);
    rf_image ti = {f->tex, TW, TH, 3, TW * 3};
    f->t = rf_texture_new(&ti, err);
    f->w = rf_work_new();
    return f->tex && f->t && f->w ? 0 : -1;
}

#endif
