/* poseinfer.h -- libposeinfer: camera frame -> sphere orientation.
 *
 * Frame (file, memory, camera) -> preprocessing "sphere-crop-v1" or "-v2"
 * (parameters from the model's metadata, docs/interfaces.md) -> ONNX Runtime
 * -> Euler angles (x, y, z) in degrees, R = Rz(z) Ry(y) Rx(x), body to world
 * (docs/conventions.md).
 *
 * Conventions of this API:
 * - Functions return 0 on success, -1 on failure; on failure they fill the
 *   caller's `err` (at least PI_ERR_LEN bytes) with "call: reason". The
 *   constructors return a handle, or NULL with `err` filled.
 * - Nothing here aborts on outside input (bad files, bad frames, bad models).
 * - A pi_ctx and a pi_camera are each used by one thread at a time.
 *
 * Link: host/build/libposeinfer.a plus `make -s -C host print-libs`, or
 * host/build/libposeinfer.so (which carries its own dependencies).
 */
#ifndef POSEINFER_H
#define POSEINFER_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Raised whenever a struct here changes layout (2: pi_result.circle); it is
 * also the shared library's soname version (host/Makefile reads it here), so
 * a program built against an older layout does not load this one. */
#define PI_API_VERSION 2
#define PI_ERR_LEN     256

/* Default limit on decoded frame size (pixels); larger frames are refused. */
#define PI_DEFAULT_MAX_PIXELS (64L * 1024 * 1024)

typedef struct pi_ctx pi_ctx;       /* a loaded model, ready to infer */
typedef struct pi_camera pi_camera; /* an open frame source */

typedef struct pi_options {
    int intra_threads; /* ONNX Runtime intra-op threads; 0 = library default (1) */
    int warmup_runs;   /* inference runs on a dummy tensor at open; default 1 */
    long max_pixels;   /* refuse frames with more pixels; 0 = PI_DEFAULT_MAX_PIXELS */
    int no_refine;     /* 1: the network's angles, not refined (the residual still at them) */
    double focal_px;   /* camera focal length in pixels for refinement; 0 = from the circle */
    const char
        *camera_file; /* camera file (docs/interfaces.md) for a sphere-crop-v2 model: expected
                                sphere radius, lens distortion undone before localisation; NULL = none */
} pi_options;

typedef struct pi_result {
    double x, y, z;       /* Euler angles, degrees (conventions.md) */
    double rotmat[3][3];  /* body-to-world R, row-major; valid when has_rotmat */
    int has_rotmat;       /* 1 when the model has the `rotmat` output */
    double cx, cy, r;     /* sphere found in the frame (undistorted with a camera file): centre
                              (OpenCV pixel coordinates, pixel centres at integers) and radius, pixels */
    int width, height;    /* frame size, pixels */
    double decode_ms;     /* image decode (0 for raw frames) */
    double preprocess_ms; /* find sphere, crop, resize, normalise */
    double infer_ms;      /* OrtRun */
    double total_ms;      /* decode + preprocess + infer (+ refine), wall clock */
    /* Refinement and confidence (docs/refine.md). has_confidence is 0 for a
     * model without its texture (spherepose.texture_png): then x, y, z are the
     * network's and nothing below is set. */
    int has_confidence;
    int confident;       /* 1: residual and pose within the model's thresholds */
    double residual;     /* unexplained fraction of the frame's variance in the circle */
    char note[160];      /* why not confident ("" when confident) */
    int refined;         /* 1: x, y, z (and rotmat) are refined */
    double net[3];       /* the network's angles */
    double rcx, rcy, rr; /* refined circle, continuous pixel coordinates */
    double refine_ms;
    double locate_ms; /* of preprocess_ms, finding the sphere alone (sphere-crop-v2; 0 for v1) */
    double circle[3]; /* the sphere's circle as printed, continuous pixel coordinates: the
                         one found (cx + 0.5, cy + 0.5, r), or the rim found from the refined
                         circle when a confident answer's refined radius differs from r by
                         more than RIM_CHECK_PCT %; a confident answer's centre weighed
                         against the refined centre (docs/refine.md, steps 8 and 9) */
} pi_result;

/* A raw 8-bit frame. channels: 1 (gray), 3 (BGR) or 4 (BGRA); stride in bytes
 * (0 = width * channels). A frame from pi_camera_grab belongs to the camera
 * and stays valid until the next grab or close. */
typedef struct pi_frame {
    const uint8_t *data;
    int width, height, channels;
    size_t stride;
    double decode_ms; /* time spent decoding it (unix: sources), else 0 */
} pi_frame;

/* Fill `o` with the defaults. */
void pi_options_init(pi_options *o);

/* Load a model (checks the input/output contract and the
 * spherepose.preprocess metadata), create the session and warm it up.
 * `opt` may be NULL for defaults. Returns NULL and fills err on failure. */
pi_ctx *pi_open(const char *model_path, const pi_options *opt, char *err);

/* Free everything pi_open made. NULL is fine. */
void pi_close(pi_ctx *ctx);

/* Decode an image file and infer. */
int pi_infer_file(pi_ctx *ctx, const char *path, pi_result *res, char *err);

/* Decode an encoded image (PNG, JPEG, ...) held in memory and infer. */
int pi_infer_memory(pi_ctx *ctx, const void *buf, size_t len, pi_result *res, char *err);

/* Infer on a raw frame (BGR, gray or BGRA, see pi_frame). */
int pi_infer_frame(pi_ctx *ctx, const pi_frame *frame, pi_result *res, char *err);

/* Convenience: pi_infer_frame on a BGR buffer of width x height, stride bytes
 * per row (0 = width * 3). */
int pi_infer_bgr(pi_ctx *ctx, const uint8_t *bgr, int width, int height, size_t stride,
                 pi_result *res, char *err);

/* Preprocess only: write the network input (float32, [3, S, S], S =
 * pi_input_size) for a raw frame into `out` (n floats, n >= 3*S*S). For
 * comparing with the Python reference and for tools. */
int pi_preprocess_frame(pi_ctx *ctx, const pi_frame *frame, float *out, size_t n, pi_result *res,
                        char *err);

/* Side S of the network input. */
int pi_input_size(const pi_ctx *ctx);

/* Which versions of the runtime's own per-pixel loops run on this processor,
 * e.g. "localisation AVX-512, refinement AVX-512": the same answers on every
 * processor (the AVX-512 refinement's within rounding: docs/refine.md), not
 * the same time (docs/bench/host.md). A static string. */
const char *pi_cpu_paths(void);

/* A metadata value of the loaded model (e.g. "spherepose.texture"), or NULL. */
const char *pi_metadata(const pi_ctx *ctx, const char *key);

/* Open a frame source (docs/interfaces.md, "Frame sources"):
 *   /dev/videoN or an integer   V4L2 through OpenCV VideoCapture
 *   gst:<pipeline>              GStreamer pipeline through OpenCV
 *   unix:<path>                 frame server on a Unix stream socket
 * timeout_ms bounds connect and each grab for unix: sources (0 = 5000). */
pi_camera *pi_camera_open(const char *spec, int timeout_ms, char *err);

/* Grab the next frame into *frame (owned by the camera, see pi_frame). */
int pi_camera_grab(pi_camera *cam, pi_frame *frame, char *err);

/* Grab the next frame and infer on it (decode time included in res). */
int pi_infer_camera(pi_ctx *ctx, pi_camera *cam, pi_result *res, char *err);

/* Close the source. NULL is fine. */
void pi_camera_close(pi_camera *cam);

/* Save a raw frame as an image file (format from the extension). */
int pi_frame_save(const pi_frame *frame, const char *path, char *err);

/* ---- measurement (bench/infer_bench.c) ---------------------------------- */

/* Make pi_now_ms (and so every time in pi_result) measure process CPU time
 * instead of wall time: for benchmarks on a machine shared with other work,
 * where wall time mostly measures the neighbours. Process-wide. */
void pi_use_cpu_clock(int on);

/* The clock of pi_result's times, in milliseconds: monotonic wall time, or
 * process CPU time after pi_use_cpu_clock(1). */
double pi_now_ms(void);

/* Read and decode an image file as pi_infer_file does, without inferring.
 * The frame is held by ctx and stays valid until its next call. */
int pi_load_file(pi_ctx *ctx, const char *path, pi_frame *frame, char *err);

/* Run the model once on the tensor already in ctx's input buffer (the last
 * preprocessed frame, or zeros): bare OrtRun, the benchmark's baseline. */
int pi_run_only(pi_ctx *ctx, char *err);

#ifdef __cplusplus
}
#endif

#endif /* POSEINFER_H */
