// kernels.h -- fast, exact versions of the image steps of sphere-crop-v1.
//
// Each function gives the same bytes as the OpenCV call it stands in for
// (named beside it); tests/host/unit/test_kernels.cpp holds them to that on
// random inputs. They exist because the generic OpenCV calls spent most of
// the preprocessing time (docs/bench/host.md). C++ only, used by shim.cpp.
#ifndef POSEINFER_KERNELS_H
#define POSEINFER_KERNELS_H

#include <cstddef>
#include <cstdint>
#include <vector>

namespace kern
{

// A BGR pixel is foreground when any channel lies outside [lo_c, hi_c]
// (lo_c > hi_c: every value is outside). Bounding box of the foreground
// over the whole frame: the same as boundingRect(~inRange(frame, lo, hi)).
// Returns false when there is no foreground pixel.
bool fg_bbox(const uint8_t *bgr, int w, int h, size_t stride, const int lo[3], const int hi[3],
             int *x0, int *y0, int *x1, int *y1);

// The foreground mask (255 / 0) of the rectangle (rx, ry, rw, rh) of the
// frame, into mask (rw x rh, row stride rw): ~inRange on that rectangle.
void fg_mask(const uint8_t *bgr, size_t stride, int rx, int ry, int rw, int rh, const int lo[3],
             const int hi[3], uint8_t *mask);

// Morphological closing of a 0/255 mask (w x h, stride w) in place with a
// structuring element (k x k, 0/1, anchor at its centre) whose rows are each
// one run of ones: morphologyEx(MORPH_CLOSE) with the default border.
// Returns false (mask untouched) for an element it does not handle.
bool close_binary(uint8_t *mask, int w, int h, const uint8_t *elem, int k);

// INTER_AREA reduction of a 3-channel 8-bit image by a non-integer factor
// >= 1 on both axes: cv::resize(..., INTER_AREA), same arithmetic. Returns
// false when the sizes ask for another path of cv::resize (enlarging, or
// an integer factor on both axes), which the caller then uses.
bool resize_area_c3(const uint8_t *src, int sw, int sh, size_t sstride, uint8_t *dst, int dw,
                    int dh, size_t dstride);

} // namespace kern

#endif
