/* shim.h -- the C interface of the OpenCV C++ shim (shim.cpp): decoding,
 * preprocessing "sphere-crop-v1", VideoCapture, image writing. No C++ type
 * and no exception crosses this interface. */
#ifndef PI_SHIM_H
#define PI_SHIM_H

#include <stddef.h>

#include "poseinfer.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Preprocessing parameters (docs/interfaces.md, "sphere-crop-v1"). */
typedef struct pp_params {
    int size;
    double margin, fg_threshold, border_frac, close_frac, min_area_frac;
    float mean[3], std[3];
} pp_params;

/* Sphere found by steps 1-5, and the background colour of step 1. */
typedef struct pp_circle {
    double cx, cy, r;
    double bg[3];
} pp_circle;

/* The defaults of docs/interfaces.md. */
void pp_defaults(pp_params *p);

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
int shim_decode(shim_mat *m, const void *buf, size_t len, long max_pixels,
                pi_frame *out, char *err);

/* Steps 1-8: frame -> out[3*size*size] (float32 CHW, RGB). Fills *c. The
 * no-sphere error text is exactly "no sphere found in frame". */
int shim_preprocess(const pi_frame *f, const pp_params *p, float *out,
                    pp_circle *c, char *err);

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
