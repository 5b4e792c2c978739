/* shim.h -- the C interface of the OpenCV C++ shim (shim.cpp): decoding,
 * preprocessing "sphere-crop-v1" and "-v2", VideoCapture, image writing. No C++ type
 * and no exception crosses this interface. */
#ifndef PI_SHIM_H
#define PI_SHIM_H

#include <stddef.h>

#include "poseinfer.h"

#ifdef __cplusplus
extern "C" {
#endif

/* A camera file (docs/interfaces.md, "Camera file"): set = 0 when none. */
typedef struct pp_camera {
    int set;
    int width, height;
    double focal_mm, pixel_mm, distance_mm, sphere_diameter_mm;
    int has_principal;
    double principal[2];  /* continuous pixel coordinates */
    double distortion[5]; /* OpenCV k1 k2 p1 p2 k3 */
    int distorted;        /* any coefficient non-zero */
} pp_camera;

/* Preprocessing parameters (docs/interfaces.md, "Preprocessing"): version 1
 * ("sphere-crop-v1") or 2 ("sphere-crop-v2"), each with its own keys. */
typedef struct pp_params {
    int version;
    int size;
    double margin;
    float mean[3], std[3];
    /* sphere-crop-v1 */
    double fg_threshold, border_frac, close_frac, min_area_frac;
    /* sphere-crop-v2 (names as in the metadata) */
    double r_min_frac, r_max_frac, r_tol;
    int coarse_size, candidates, rays, fine_passes, irls_iters;
    double coarse_rbin, edge_min, cand_frac, cand_gap, ray_edge_min;
    double consensus_cells, consensus_px, consensus_step_px, consensus_reach, consensus_edge_ratio;
    double fine_window_px, fine_window_frac, tukey_c, sigma_min_px, inlier_px;
    double support_edge_min, support_ratio, support_flank_px;
    double min_support, max_cut, mask_frac, fill[3];
    /* the camera (v2): expected radius, undistortion; its map (shim_camera_prepare) */
    pp_camera cam;
    const void *undistort;
} pp_params;

/* Sphere found by steps 1-5, and the background colour of step 1. */
typedef struct pp_circle {
    double cx, cy, r;
    double bg[3];
    double locate_ms; /* sphere-crop-v2: time finding the circle alone (pi_now_ms), else 0 */
    double cov[3];    /* sphere-crop-v2: the centre's covariance from its rims (crop2.h
                         find_sphere), px^2; NaN when none; v1 leaves it */
} pp_circle;

/* The v2 parameters from the metadata object (pp_v2.c): every key present,
 * none unknown, each in its range; errors name the key and the model. */
struct json_value;
int pp_parse_v2(const struct json_value *root, pp_params *p, char *err, const char *model);

/* Read a camera file (pp_v2.c). Errors name the file and the key. */
int pp_camera_load(const char *path, pp_camera *cam, char *err);

/* Build the undistortion map of p->cam (when it has distortion) into
 * p->undistort; shim_camera_free releases it. */
int shim_camera_prepare(pp_params *p, char *err);
void shim_camera_free(pp_params *p);

/* Whether sphere-crop-v2's AVX-512 steps run on this processor (crop2.h). */
int shim_crop2_avx512(void);

/* A holder for decoded pixels (a cv::Mat inside). */
typedef struct shim_mat shim_mat;
shim_mat *shim_mat_new(void);
void shim_mat_free(shim_mat *m);

/* Size of an encoded image from its header, without decoding. Returns 0 and
 * sets *w, *h; 1 when the format is not one this parser knows (decode will
 * tell); -1 with err for a header that is clearly broken. */
int shim_probe_size(const unsigned char *buf, size_t len, long *w, long *h, char *err);

/* Decode an encoded image into m (8-bit, 1/3/4 channels kept as they are)
 * and describe it in *out. Refuses frames over max_pixels. */
int shim_decode(shim_mat *m, const void *buf, size_t len, long max_pixels, pi_frame *out,
                char *err);

/* Frame -> out[3*size*size] (float32 CHW, RGB), by p->version. Fills *c
 * (v2: bg is the fill colour). Errors: "no sphere found in frame", and for
 * v2 "two spheres in frame (...)", "sphere cut by the frame edge (...)",
 * "frame is WxH, the camera file's calibration is for WxH". */
int shim_preprocess(const pi_frame *f, const pp_params *p, float *out, pp_circle *c, char *err);

/* shim_preprocess, and *seen: the frame the circle lies in, which refinement
 * must read (docs/refine.md). With a camera that has distortion that is the
 * undistorted frame (BGR), kept in `und` until its next use; otherwise (and
 * when und is NULL) *f itself, not copied. */
int shim_preprocess_seen(const pi_frame *f, const pp_params *p, float *out, pp_circle *c,
                         shim_mat *und, pi_frame *seen, char *err);

/* sphere-crop-v2: the sphere's rim found from a circle measured another way
 * (crop2.h rim_from), in a frame as *seen gives it (1, 3 or 4 channels);
 * circle and result in OpenCV pixel coordinates; cov (3, when not null) its
 * centre's covariance, NaN when none. Returns 0, 1 when fewer than 8 rims
 * were found or none lies near the refitted circle (the circle stands), -1
 * with err (out of memory). */
int shim_rim_from(const pi_frame *f, const pp_params *p, double cx, double cy, double r,
                  double *ocx, double *ocy, double *orad, double *cov, char *err);

/* Write a frame to an image file (format from the extension). */
int shim_save(const pi_frame *f, const char *path, char *err);

/* VideoCapture for "/dev/videoN", an integer, or "gst:<pipeline>". */
typedef struct shim_cap shim_cap;
shim_cap *shim_cap_open(const char *spec, char *err);
int shim_cap_grab(shim_cap *c, pi_frame *out, char *err);
void shim_cap_close(shim_cap *c);

#ifdef __cplusplus
}
#endif

#endif
