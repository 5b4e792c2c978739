"""Lens distortion of rendered frames: OpenCV's model applied to a pinhole render by remapping.

The renderer draws an ideal pinhole image. A real lens moves each point from
its undistorted position p_u to its distorted position p_d = distort(p_u)
(OpenCV: k1, k2, k3 radial, p1, p2 tangential, around the principal point).
The frame the camera delivers has at each pixel p_d the pinhole image's
value at p_u = undistort(p_d); that inverse is what cv2.undistortPoints
computes (iteratively). So `cv2.undistort(frame, K, dist)` gives back the
pinhole image (up to resampling), which is what the runtime does.

Speed: the inverse is evaluated on a coarse grid (every GRID_STEP pixels) and
interpolated bilinearly; the distortion field is smooth, so the
interpolation error is far below a hundredth of a pixel at the distortions
a camera file allows (checked in tests/sim/test_sim_scene.py by the
round trip through cv2.undistort).

Pixels whose pinhole position falls outside the pinhole image (barrel
distortion pulls the frame's corners in from beyond its edges) read from a
margin the renderer draws around the frame (`margin_px`); beyond that the
border repeats.
"""
import math

import cv2
import numpy as np

GRID_STEP = 16
MAX_MARGIN = 96  # px; a wider lens needs more than a pinhole render can sensibly supply


def opencv_matrix(focal_px, principal):
    """OpenCV camera matrix for focal length f (px) and principal point (u0, v0) in continuous pixels."""
    u0, v0 = principal
    return np.array([[focal_px, 0.0, u0 - 0.5], [0.0, focal_px, v0 - 0.5], [0.0, 0.0, 1.0]])


_GRIDS = {}


def _fine_grid(width, height):
    """Every pixel's position in units of the coarse grid (cached per size)."""
    g = _GRIDS.get((width, height))
    if g is None:
        g = _GRIDS[(width, height)] = np.meshgrid(np.arange(width, dtype=np.float32) / GRID_STEP,
                                                  np.arange(height, dtype=np.float32) / GRID_STEP)
    return g


def undistort_map(width, height, focal_px, principal, distortion):
    """float32 maps (x, y) [H, W]: for each frame pixel (OpenCV integer coordinates), where it lies in
    the pinhole image. Evaluated every GRID_STEP pixels and interpolated bilinearly."""
    K = opencv_matrix(focal_px, principal)
    dist = np.asarray(distortion, np.float64)
    nx = int(math.ceil((width - 1) / GRID_STEP)) + 1
    ny = int(math.ceil((height - 1) / GRID_STEP)) + 1
    gx, gy = np.meshgrid(np.arange(nx, dtype=np.float64) * GRID_STEP, np.arange(ny, dtype=np.float64) * GRID_STEP)
    pts = np.stack([gx.ravel(), gy.ravel()], axis=1).reshape(-1, 1, 2)
    und = cv2.undistortPointsIter(pts, K, dist, None, K,
                                  (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-6))
    coarse = und.reshape(ny, nx, 2).astype(np.float32)
    # Bilinear interpolation of the coarse grid at every pixel: remap the coarse map itself.
    fx, fy = _fine_grid(width, height)
    full = cv2.remap(coarse, fx, fy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return np.ascontiguousarray(full[..., 0]), np.ascontiguousarray(full[..., 1])


def margin_px(width, height, focal_px, principal, distortion):
    """Pixels the pinhole render must extend beyond the frame on each side so that every frame pixel
    reads from drawn pixels (0 without distortion), capped at MAX_MARGIN."""
    if not any(distortion):
        return 0
    mx, my = undistort_map(width, height, focal_px, principal, distortion)
    over = max(0.0, -float(mx.min()), -float(my.min()),
               float(mx.max()) - (width - 1), float(my.max()) - (height - 1))
    return min(MAX_MARGIN, int(math.ceil(over)) + 2)


def distort(image, focal_px, principal, distortion, margin=0):
    """The frame a lens with `distortion` delivers, from a pinhole `image` of the frame plus `margin`
    pixels on each side (the frame's principal point and focal length, in frame pixels)."""
    h, w = image.shape[0] - 2 * margin, image.shape[1] - 2 * margin
    mx, my = undistort_map(w, h, focal_px, principal, distortion)
    if margin:
        mx += margin
        my += margin
    return cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
