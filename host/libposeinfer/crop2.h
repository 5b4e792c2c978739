// crop2.h -- preprocessing "sphere-crop-v2" (docs/interfaces.md): the
// sphere's circle from colour edges in a frame with a mounting post and
// clutter, and the crop that keeps only the inside of that circle. The same
// arithmetic, in the same order, as training/preprocess.py, so both give
// the same circle and the same crop bytes (tests/host/test_parity.py).
// C++ only, used by shim.cpp.
#ifndef POSEINFER_CROP2_H
#define POSEINFER_CROP2_H

#include <cstddef>
#include <cstdint>
#include <vector>

#include "shim.h"

namespace crop2
{

// The circle of the sphere in a BGR frame (OpenCV pixel coordinates: pixel
// centres at integers). Returns 0, or -1 with err ("no sphere found in
// frame", "two spheres in frame (...)", "sphere cut by the frame edge (...)").
// cov (when not null): the covariance of the centre from its rims, (cxx, cxy,
// cyy) in px^2 (preprocess.py find_sphere's cov), NaN when there is none.
int find_sphere(const uint8_t *bgr, int w, int h, size_t stride, const pp_params *p, double *cx,
                double *cy, double *r, double *cov, char *err, size_t errlen);

// The sphere's rim found from a circle measured another way, the
// refinement's (preprocess.py rim_from): on each of the circle's support rays
// the step peak nearest it, moved to its outer half-maximum, and the circle
// refitted through those rims. Returns 0, or -1 with fewer than 8 rims or
// none of them near the refitted circle. cov (when not null): the covariance
// of the result's centre from those rims, as find_sphere's.
int rim_from(const uint8_t *bgr, int w, int h, size_t stride, const pp_params *p, double cx,
             double cy, double r, double *ocx, double *ocy, double *orad, double *cov);

// Crop (steps after the circle): the square of side 2 r margin around it,
// outside the frame `fill`, reduced to size x size (INTER_AREA), every output
// pixel farther than r (1 + mask_frac) from the centre set to `fill`. Writes
// size * size * 3 BGR bytes to out.
void crop(const uint8_t *bgr, int w, int h, size_t stride, double cx, double cy, double r,
          const pp_params *p, uint8_t *out);

// The undistortion map of a camera for a w x h frame: source positions in
// 1/32 pixel (cv2.remap's fixed point), computed as preprocess.py does.
struct UndistortMap {
    int w = 0, h = 0;
    std::vector<int64_t> mx, my;
    // the same, ready to use: top-left corner, weights in 1/32, and whether
    // all four corners are inside the frame
    std::vector<int32_t> x0, y0;
    std::vector<uint8_t> ax, ay, inside;
};
void undistort_map(const pp_camera *cam, int w, int h, UndistortMap *m);

// out (w x h BGR, packed) = the frame resampled through the map, bilinear
// with 1/32 weights, 0 outside.
void remap(const uint8_t *bgr, size_t stride, const UndistortMap &m, uint8_t *out);

// The 8 ray directions' construction (Taylor series, no libm), exposed for
// the unit tests: k unit vectors at angles 2 pi i / k (k a multiple of 8).
std::vector<double> ray_dirs(int k);

// Whether the steps written with AVX-512 intrinsics (crop2.cpp) run, or their
// portable versions: on < 0, when the processor has AVX-512F (the default);
// 0, never; else when the processor has it. Returns whether they run now.
// For tests (both must give the same bits): not thread-safe.
int set_avx512(int on);

// Whether those steps run now (what set_avx512 last left), without changing it.
int uses_avx512();

// For tests, by the steps set_avx512 picks: one row's coarse edges (mc the
// row's magnitudes^2, up and dn the rows above and below, each of gw values
// with one more before and after; gx, gy the row's gradient) as x, gx, gy
// per kept pixel in order; and the step peaks of score[0 .. n) at least thr
// (their indexes, in order).
std::vector<int32_t> row_edges_of(const int32_t *up, const int32_t *mc, const int32_t *dn,
                                  const int32_t *gx, const int32_t *gy, int gw, int32_t tmin);
std::vector<int32_t> peaks_of(const double *score, long n, double thr);

} // namespace crop2

#endif
