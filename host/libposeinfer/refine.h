/* refine.h -- render-and-compare refinement of a pose, and its alignment
 * residual (plain C, no OpenCV). The algorithm and its parameters are those
 * of training/refine.py, the reference; docs/refine.md describes both. */
#ifndef PI_REFINE_H
#define PI_REFINE_H

#include <stddef.h>
#include <stdint.h>

#include "sp_euler.h"

#define RF_META_TEXTURE    "spherepose.texture_png"
#define RF_META_CONFIDENCE "spherepose.confidence" /* confidence.h reads it */

/* The parameters of training/refine.py (tests/host/unit/test_refine.c reads
 * them back from the Python file). */
#define RF_LEVELS        3
/* one line each: tests/training/test_refine.py reads them */
// clang-format off
#ifndef RF_ITERS_INIT
#define RF_ITERS_INIT {4, 2, 1} /* Levenberg-Marquardt steps per level, coarse to fine */
#endif
#ifndef RF_STRIDES_INIT
#define RF_STRIDES_INIT {2, 3, 5} /* pixel sampling stride per level, coarse to fine */
#endif
// clang-format on
#define RF_RHO_MAX       0.92
#define RF_CROP_PAD      4.0 /* the crop: the circle's square grown by this (px) */
#define RF_TEXTURE_WIDTH 1024
#define RF_DAMPING       1e-3
#define RF_MAX_STEP_DEG  3.0
#define RF_REF_D_OVER_R  12.5
#define RF_LUMA_B        0.114 /* a gray frame sees the texture as its luma */
#define RF_LUMA_G        0.587
#define RF_LUMA_R        0.299

/* The texture pyramid (finest RF_TEXTURE_WIDTH wide). */
typedef struct rf_texture rf_texture;

/* Working memory reused between frames. */
typedef struct rf_work rf_work;

typedef struct rf_image {
    const uint8_t *data; /* 8-bit pixels, channels 1 (gray), 3 (BGR) or 4 (BGRA) */
    int width, height, channels;
    size_t stride; /* bytes per row */
} rf_image;

typedef struct rf_out {
    double R[3][3];   /* refined body-to-world rotation */
    double euler[3];  /* the same as (x, y, z) degrees */
    double cx, cy, r; /* refined circle, continuous pixel coordinates */
    double residual;  /* unexplained fraction of the frame's variance, [0, 1] */
    double colour;    /* the frame's colour share over the fitted rendering's (NaN: a gray frame) */
    int iterations;   /* Levenberg-Marquardt steps kept */
} rf_out;

/* Texture from decoded pixels (an equirectangular image, width = 2 x height,
 * width a multiple of RF_TEXTURE_WIDTH / 4 and at least RF_TEXTURE_WIDTH).
 * NULL with err (RF_TEXTURE_ERR_LEN bytes at least) filled when it does not fit. */
#define RF_TEXTURE_ERR_LEN 160
rf_texture *rf_texture_new(const rf_image *img, char *err);
void rf_texture_free(rf_texture *t);

rf_work *rf_work_new(void);
void rf_work_free(rf_work *w);

/* Refine R0 (body to world, row-major) and the circle (cx, cy, r)
 * (continuous pixel coordinates of the undistorted frame) against the
 * texture. focal_px: the camera's focal length in pixels, 0 to derive it from
 * r and the reference camera. steps = 0: no refinement, only the residual at
 * R0 and the circle. Returns 0, or -1 with err (too small a circle, out of
 * memory). */
int rf_refine(const rf_texture *t, rf_work *w, const rf_image *frame, double cx, double cy,
              double r, const double R0[3][3], double focal_px, int steps, rf_out *out, char *err,
              size_t errlen);

/* The convergence check (training/refine.py CHECK_*, refine_checked): a gray
 * frame, or an answer whose first pass moved the circle's centre or radius
 * more than RF_CHECK_PX pixels or the pose more than RF_CHECK_DEG from the
 * network's, is refined again from itself, RF_CHECK_PASSES passes at most. */
#define RF_CHECK_PASSES 4
#define RF_CHECK_PX     2.0
#define RF_CHECK_DEG    2.5

/* The circle after refinement (training/refine.py RIM_CHECK_PCT): a confident
 * answer whose refined radius differs from the localisation's by more than
 * this many percent gets the rim found from the refined circle as its circle
 * (sphere-crop-v2). */
#define RF_RIM_CHECK_PCT 0.2

/* The printed centre, a confident answer's (training/refine.py
 * CENTRE_FUSE_PX, fused_centre): the localisation's (or that rim's) c weighed
 * against the refined centre f, c + C (C + CENTRE_FUSE_PX^2 I)^-1 (f - c), C
 * the covariance of c (cxx, cxy, cyy: crop2 find_sphere's or rim_from's
 * cov). */
#define RF_CENTRE_FUSE_PX 0.1
void rf_fused_centre(double cx, double cy, const double cov[3], double fx, double fy, double *ox,
                     double *oy);

/* The angle of the rotation from B to A, degrees. */
double rf_rotation_deg(const double A[3][3], const double B[3][3]);

/* rf_refine and the convergence check (training/refine.py refine_checked):
 * out is the last pass's, *moved that pass's rotation in degrees (NaN when
 * the answer was not checked, and with steps = 0); passes stop at one that
 * moves at most converge_max_deg. Returns rf_refine's 0 or -1 with err. */
int rf_refine_checked(const rf_texture *t, rf_work *w, const rf_image *frame, double cx, double cy,
                      double r, const double R0[3][3], double focal_px, int steps,
                      double converge_max_deg, rf_out *out, double *moved, char *err,
                      size_t errlen);

/* Conventions' conversions (docs/conventions.md); Euler angles to R is
 * sp_euler_to_matrix (sp_euler.h). */
void rf_matrix_to_euler(const double R[3][3], double euler_deg[3]);

/* Base64 (RFC 4648, no line breaks) to bytes: *out malloc'ed. -1 on bad text. */
int rf_base64_decode(const char *text, unsigned char **out, size_t *len);

/* The versions of the per-pixel loops (refine.c), lowest first: each one's
 * number and name (pi_cpu_paths reports the name). The portable version is
 * the plain C loops: the only one on other processors (aarch64) and in a
 * clang build; on x86-64 (GCC) tests and benches can pick it with
 * rf_set_version. All versions but AVX-512 give the same bits. */
// clang-format off
#define RF_VERSION_LIST(X) X(RF_V_PORTABLE, "portable") X(RF_V_BASELINE, "x86-64 baseline") \
                           X(RF_V_AVX2, "AVX2") X(RF_V_AVX512, "AVX-512")
// clang-format on
#define RF_VERSION_ENUM_(id, name) id,
enum { RF_VERSION_LIST(RF_VERSION_ENUM_) RF_V_COUNT };

/* Which version of the per-pixel loops runs: v < 0, the best the processor
 * has (the default); else v, or the best there is when that is lower.
 * Returns the version now in effect. For tests: not thread-safe. */
int rf_set_version(int v);

/* The version of the per-pixel loops in effect, without changing it. */
int rf_version_in_use(void);

#endif
