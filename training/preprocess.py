"""Preprocessing: a camera frame -> the network input tensor.

Two algorithms, chosen by the parameters' "name" (docs/interfaces.md gives
both step by step; host/ implements the same steps in C++ and is tested
against this, byte for byte):

- "sphere-crop-v2" (the default for new models): the sphere's circle from
  colour edges (gradient-direction Hough vote on a reduced image, then
  sub-pixel edges along rays from the centre and a robust circle fit), so a
  mounting post, a cluttered or uneven background and vignetting do not move
  it; the crop keeps only the inside of that circle, everything else one
  constant colour. Optional camera calibration: expected radius, lens
  distortion (undistorted first).
- "sphere-crop-v1" (older models): border-median background, threshold,
  largest blob, enclosing circle.

The parameters are written into every exported model's metadata. The v2
arithmetic is written so that C++ can repeat it exactly: integers where
possible, float64 element by element, sums in a fixed sequential order,
no libm function but sqrt.
"""
import json
import math

import cv2
import numpy as np

NAME_V1 = "sphere-crop-v1"
NAME_V2 = "sphere-crop-v2"
NAME = NAME_V2

DEFAULTS_V1 = {
    "name": NAME_V1,
    "size": 128,
    "margin": 1.15,
    "fg_threshold": 40,
    "border_frac": 0.02,
    "close_frac": 0.03,
    "min_area_frac": 0.002,
    "mean": [0.485, 0.456, 0.406],
    "std": [0.229, 0.224, 0.225],
}

DEFAULTS_V2 = {
    "name": NAME_V2,
    "size": 128,
    "margin": 1.15,
    "mean": [0.485, 0.456, 0.406],
    "std": [0.229, 0.224, 0.225],
    # radius search range: without a camera file, fractions of min(H, W);
    # with one, the expected radius times 1 -/+ r_tol
    "r_min_frac": 0.05,
    "r_max_frac": 0.5,
    "r_tol": 0.15,
    # coarse stage: the frame reduced by s = max(1, min(H, W) // coarse_size)
    # (block means); its Sobel edges (channel of the largest gradient, at least
    # edge_min, thinned across the edge) vote along their gradient direction
    # for (centre, radius bin about coarse_rbin * radius wide); the `candidates`
    # best peaks with at least cand_frac of the best's votes go on, each one
    # farther than cand_gap times the smallest radius from the ones before (a
    # frame with a camera file and no sphere found: searched again with the
    # wide search's smallest radius there, _find_sphere_v2)
    "coarse_size": 170,
    "coarse_rbin": 0.08,
    "edge_min": 24,
    "candidates": 4,
    "cand_frac": 0.35,
    "cand_gap": 0.25,
    # fine stage, per candidate: `rays` rays from the centre; edge candidates
    # on each (local maxima of at least ray_edge_min of the colour step over
    # 1 px); first pass: the centre shift within +-w, w = consensus_cells * s
    # + consensus_px (grid of consensus_step_px), and radius that most rays
    # agree on, from candidates within +-consensus_reach * w of the radius;
    # in the first pass only edges of at least consensus_edge_ratio times their
    # ray's median step count (a busy texture or backdrop has steps all along
    # a ray; the rim stands out of them); every pass: irls_iters rounds of
    # "nearest candidate per ray, Tukey weights (tukey_c times the robust
    # scale, at least sigma_min_px), algebraic circle fit"; passes after the first cast the rays again from
    # the new centre, within +-(fine_window_px + fine_window_frac * r)
    "rays": 128,
    "ray_edge_min": 12,
    "consensus_cells": 4,
    "consensus_px": 4,
    "consensus_step_px": 2,
    "consensus_reach": 1.5,
    "consensus_edge_ratio": 2.0,
    "fine_passes": 3,
    "fine_window_px": 3,
    "fine_window_frac": 0.02,
    "irls_iters": 6,
    "tukey_c": 4.0,
    "sigma_min_px": 0.3,
    # support of a circle: the fraction of all rays with an edge within
    # inlier_px of it that stands out of the ray's own steps nearby: a local
    # maximum of the colour step of at least support_edge_min and at least
    # support_ratio times the median step on the ray from 2 inlier_px to
    # support_flank_px off the circle (sensor noise and texture are edges
    # everywhere along a ray, a rim only at the circle). The sphere is the best
    # supported circle with at least min_support; another one of about its
    # size (radii within 1 + 2 r_tol) away from it is a second sphere (error);
    # more than max_cut of its rim outside the frame is an error too
    "inlier_px": 1.0,
    "support_edge_min": 8,
    "support_ratio": 2.5,
    "support_flank_px": 8,
    "min_support": 0.42,
    "max_cut": 0.15,
    # crop: everything farther than r (1 + mask_frac) from the centre is `fill` (BGR)
    "mask_frac": 0.02,
    "fill": [128, 128, 128],
}

DEFAULTS = DEFAULTS_V2

# The weak fit's retries (_grow, and the sphere's _tangent; step 5 of docs/interfaces.md) stop
# after this many rounds: each round that moves raises the support, so the retries end anyway,
# but this bounds a frame's time. The 612 measurement frames took at most 4 _grow tries (3 that
# move). A constant of the algorithm, not a model parameter (a model's metadata holds every
# parameter, with no default); host/libposeinfer/crop2.cpp has the same (grow_rounds).
GROW_ROUNDS = 8

# A second circle of the sphere's size is a second sphere (an error) unless its colours are not the
# sphere's (COLOUR_TOL) or its inside is flat where the sphere's darkens towards its rim
# (_limb_shading: a lit sphere's limb is darker than its middle, and its texture's dark bands
# reach the rim; a disk of clutter or a pattern of the backdrop is as bright at its edge as
# inside): its shading above 1 less than LIMB_SHARE of the
# sphere's, when the sphere's is at least LIMB_MIN (a sphere over-exposed to its rim shows no
# shading, and then nothing is told apart). On the development frames (the ray-caster's
# `refuse` family, seeds 0 and 136-140: 198 second spheres in 191 frames) the first sphere's
# shading is 1.33-3.4 and a second sphere's shading above 1 at least 0.53 of the first's; a
# clutter disk's and a checkerboard circle's 0.04 and 0.11 of it. Constants of the algorithm, not
# model parameters; host/libposeinfer/crop2.cpp has the same (limb_share, limb_min).
LIMB_SHARE = 0.25
LIMB_MIN = 1.25

# A second sphere partly outside the frame (rays leaving the frame count as without support, so
# its support can fall below min_support although its rim is clear wherever it is in the frame)
# is judged by its rays in the frame (_in_frame_support): a circle with at least SECOND_IN_FRAME
# of its rays in the frame (about 30 % of its rim outside at most) is a second sphere when
# min_support of those rays support it, as a whole circle's would (with the other rules: size,
# centres, _flat, _alike, and its rays on the sphere's disc counted as without: _beside_support).
# Measured on the development frames (seeds 0, 111-135, 136-140 and the training renderer's val
# sets): the known case, a `refuse` seed 139 second sphere 20 % outside
# the frame, has 0.77 of its rays in it (in-frame support 0.53); circles of clutter disks cut by
# the frame edge beside a sphere that must be answered have at most 0.59 (75 of 128 rays; in-frame
# support 0.44-0.52; refused from 0.55 down). On 300 frames of bench/raycast's `two-edge` family
# (seeds 500-502, the second sphere 10-45 % outside) 290 are refused with 0.7, 286 without the
# rule, 293 with 0.6 (2 rays above those clutter circles). A constant of the algorithm, not a
# model parameter; host/libposeinfer/crop2.cpp has the same (second_in_frame).
SECOND_IN_FRAME = 0.7

# The sphere's circle cut by the frame edge is said to be one (the error names the cut) only when
# its inside is no darker than its edge (_limb_shading over its rays in the frame at least
# CUT_SHADE: a lit sphere is brightest inside), else the frame has no sphere found; with no
# sphere found, a circle cut by the frame edge that is a sphere's (at least half its rays in the
# frame, min_support of them supporting it, that shading) is named instead. Only the message
# changes, and with it whether a frame with a camera file is searched again (only "no sphere
# found" is: _find_sphere_v2). On the development frames the shading of every cut sphere (the
# `refuse` frames of the kind `cut`, seeds 0 and 136-140: 211) is at least 1.13; a dark clutter
# disk cut by the edge that rose above a training-renderer frame's sphere 0.36, and the cut
# circles that pass the other tests in frames without a sphere at most 0.75. A constant of the
# algorithm, not a model parameter; crop2.cpp has the same (cut_shade).
CUT_SHADE = 1.0

# ... and only when it shows the printed texture's bands: `_texture_steps` (the median count of colour
# steps per ray from 0.2 r to 0.8 r over its rays in the frame) at least CUT_TEXTURE, or too few rays
# in the frame to tell. A lit clutter disk cut by the frame edge is smooth inside. Measured
# (docs/bench/localise.md) on the 943 frames named "sphere cut by the frame edge" before this test
# (seeds 475-502 of the four rig families, `refuse` alone for 479-482; `two-edge` 500-502): the 930
# spheres truly cut (`refuse` frames of the kind `cut`) show 2-17 steps (p5 3, median 4); 9 of the
# 11 frames without a sphere named so show 0 or 1 (busy clutter has steps too: on fresh seeds
# 503-510 it mends 2 of 5). Only the message changes (and with it whether the frame is searched
# again, as above). A constant of the algorithm, not a model parameter; crop2.cpp has the same
# (cut_texture).
CUT_TEXTURE = 2.0

# A circle of the sphere's size beside it, supported by at least SECOND_RETRY of the rays but
# below min_support, is tried again as the sphere's weak fit is (_grown: _grow's larger and
# smaller circles) before it is ruled out as a second sphere: the fine passes from a coarse peak
# a few pixels off a second sphere can settle on its texture bands as they can on the sphere's
# (a held-out `refuse` frame of seed 405, two spheres on clutter: the second's fit 0.33, from
# _grow's circles 0.69, answered with a confident pose without this). Only such circles do the
# work: on the 2 700 development frames (seeds 0, 111-135, 136-140, 401-402 and the training
# renderer's val sets) no frame changes, answered or refused, and no circle moves. A circle from
# min_support to below (1 + min_support) / 2 that is not a second sphere as it is
# (_second_beside: e.g. _flat, its inside as bright as its edge) is tried the same way, until
# (1 + min_support) / 2, and judged again when it moves: a second sphere's fit 3-4 px too large on
# one side reaches the backdrop there and its limb shading looks flat (a held-out `refuse` frame
# of seed 460: 0.422 and shading 1.10, grown 0.69 and 2.54, answered with a confident pose
# without this); on the 9 400 development frames (seeds 418-429 and 432-441, two-edge 500-502,
# rig-photo 501-503) no frame changes. A constant of the algorithm, not a model parameter;
# host/libposeinfer/crop2.cpp has the same (second_retry).
SECOND_RETRY = 0.25

# A circle tried again that way and still below min_support, with at least SECOND_WEAK of support
# and of beside support, is a second sphere too when it looks like the sphere: lit as it is (its
# shading above 1 at least WEAK_SHARE of the sphere's, the sphere's at least LIMB_MIN) and
# textured as it is (_texture_steps, the median count of colour steps per ray inside the circle,
# within TEXTURE_TOL of the sphere's: the same printed texture at about the same size). Where the
# second sphere's limb darkens to a dark backdrop, or part of it lies outside the frame, its fit
# can reach only 0.35-0.41 (a held-out `refuse` frame of seed 446, two spheres on a dark gradient:
# 0.391, answered with a confident pose of the other sphere without this). Measured on the
# circles that reach SECOND_RETRY's loop with 0.30-0.42 in 13 000 development frames (seeds
# 418-429 and 432-450, two-edge 500-502, rig-photo 501-503): the 7 second spheres among them (6
# `two-edge` frames and that one) have 0.352-0.414 of beside support, shading 0.64-1.42 of the
# sphere's and texture within 1 of it. The 12 clutter circles with 0.33 or more of beside
# support beside a sphere that must be answered (11 frames) have texture 2-27.5 off the sphere's
# (10) or shading 0.33 and 0.37 of it (2), and the nearest clutter circle that passes both tests
# has 0.281 (a rig frame of seed 443). Of 261 well supported second spheres (seeds 418-441) 232
# have texture within 1 of the sphere's; of 33 clutter circles 3. The same frames are refused,
# and no other, with SECOND_WEAK 0.30-0.33, WEAK_SHARE 0.4-0.5 or TEXTURE_TOL 1-1.5. SECOND_WEAK
# was 0.33 until a fresh `refuse` frame (seed 498, -3.589_28.381_-19.451: two spheres on clutter,
# the second 2 % outside the frame) reached 0.328 of support and of beside support, lit, textured
# and coloured as the sphere is, and got a confident pose of the other; at 0.30 it is refused, and
# no other of the 9 900 frames at hand (seeds 475-498 of the four rig families, `refuse` alone for
# 479-482; `rig-photo` and `rig-sensor` 604-607, `rig-photo` 505, `two-edge` 500-505) changes
# (docs/bench/localise.md); fresh seeds 499-510 since hold it.
# Constants of the algorithm, not model parameters; crop2.cpp has the same (second_weak,
# weak_share, texture_tol).
SECOND_WEAK = 0.30
WEAK_SHARE = 0.5
TEXTURE_TOL = 1.0

# A second circle is a second sphere only when its colours are the sphere's (_alike): a clutter
# disk, a helmet or an engine cover of the sphere's size beside it is not, and which circle to
# measure is then clear. The colours of a circle: COLOUR_RINGS rings of samples on its rays, at
# equal areas out to COLOUR_REACH of its radius (bilinear, those in the frame; fewer than
# COLOUR_IN_FRAME of them: none, and then the circle is judged without this test: the part of a
# second sphere in the frame need not show the texture's colours in their shares), each sample
# coloured (largest minus smallest channel above COLOUR_SAT of the largest) in one of 12 hue bins
# of 30 degrees, or else dark (largest channel below COLOUR_DARK of the circle's COLOUR_QUANTILE
# quantile of it: dark relative to the circle itself, so that an all-black circle is all light)
# or light; the shares of the 14 bins (hues 0-11, dark, light). Two circles whose shares differ
# by more than COLOUR_TOL in all (the L1 distance, 0 to 2) are not the same printed texture,
# whatever its pose, light or size. Measured (docs/bench/localise.md): over the 1 026 pairs of
# two spheres with at least COLOUR_IN_FRAME of both circles' samples in the frame (`refuse` and
# `two-edge` frames of seeds 475-478, 483-498 and 500-505) the distance is at most 0.504 (p99
# 0.43); the nine circles called second spheres beside a sphere that must be answered on those
# seeds and `rig-photo` 604-607 and 505 (clutter ellipses and circles, a helmet, an engine cover)
# 0.875-1.521 with 0.946-1 of their samples in the frame. A second sphere 36 % outside the frame
# (`two-edge` s505 -24.504_-2.809_-25.068, 0.64 of its samples in it) showed 0.80: hence the
# floor. It applies to well supported second circles (_second) and to weak ones (_weak_second)
# alike; no other frame of those changes (a mono camera's frames have dark and light only: there
# it tells little). Constants of the algorithm,
# not model parameters; crop2.cpp has the same (colour_rings, colour_reach, colour_in_frame,
# colour_quantile, colour_sat, colour_dark, colour_tol).
COLOUR_RINGS = 8
COLOUR_REACH = 0.8
COLOUR_IN_FRAME = 0.9
COLOUR_QUANTILE = 0.95
COLOUR_SAT = 0.35
COLOUR_DARK = 0.35
COLOUR_TOL = 0.75

# A second sphere partly outside the frame has its edges in the frame only, and where its limb
# darkens over a dark backdrop few of those: its coarse peak can fall below cand_frac of the
# sphere's and get no fit at all (a held-out `refuse` frame of seed 462: a second sphere a quarter
# outside the left edge, 205 votes against the sphere's 636, answered with a confident pose). The
# peaks after the candidates, down to WEAK_PEAK of the best's votes (within the same 4 x
# candidates peaks, so none when `candidates` peaks not cut by the frame edge came first), whose
# coarse circle is cut by the frame edge and whose centre lies outside the sphere's circle, are
# fitted after the sphere is chosen and judged as second spheres as the other fits are (that
# frame's: support 0.56); never as the sphere. On the 9 400 development frames (seeds 418-429 and
# 432-441, two-edge 500-502, rig-photo 501-503) no frame changes, answered or refused, and no
# sphere's circle moves (one refused frame's error names another second circle); those peaks
# judged the same way in the frame too (not only cut by its edge), 10 frames with a clear sphere
# are refused by clutter disks beside it. A constant of the algorithm, not a model parameter;
# crop2.cpp has the same (weak_peak).
WEAK_PEAK = 0.25

# The sphere's circle (and a refused frame's best fit in _rescue), when supported below WIDE_BELOW
# after _tangent, is refitted once more through the outermost edges from 1.5 inlier_px inside it to
# WIDE_OUT inlier_px outside (the last refit's band reaches 2 inlier_px); in _rescue that circle is
# kept when better supported (_wide), for the sphere the last step from it when more of its rims lie
# near its result (_final_circle, RIM_NEAR). Near the limb the sphere's surface is seen edge-on, so
# a texture band's edge there runs along the rim, 2-4 px inside it, often with a larger colour step
# than the rim's over a dark backdrop; the fit can settle on such a band along one arc (a circle 1-2
# px small, off towards the other side) and stay there: the rim lies beyond the last refit's band,
# and _tangent's retries start fine_window_px and 2 fine_window_px out (3 and 6 px as shipped). On
# the 5 500 development frames (the ray-caster's seeds 0, 111-140 and 401-409, two-edge 500-502,
# rig-photo 501-503, rig-sensor 601-603, and the training renderer's val sets) 12 circles enter the
# limits of 0.5 px and 0.5 % and none leaves (rig s404 6.666_-1.074_18.715: support after _tangent
# 0.75 -> 0.85, 1.73 -> 0.05 px off centre); without the gate (every sphere) the same; with the band
# to 4 inlier_px, 2 fewer. On 1 200 fresh held-out frames (seeds 410-413) none enters and one leaves
# (0.37 -> 0.60 px). Constants of the algorithm, not model parameters; crop2.cpp has the same
# (wide_out, wide_below).
WIDE_OUT = 3.0
WIDE_BELOW = 0.86

# For the sphere itself the wider band's circle is not judged by its support: the last step
# (_outermost, _rim) runs from both circles, and the one whose rims lie nearer its own circle is
# kept: more rims within RIM_NEAR inlier_px of it, the fit's on ties (_final_circle). The support
# counts a ray within inlier_px of a circle, so a circle 1-2 px off the rim along a dark arc can
# count as many rays as the true one, or more (edge s424 3.517_18.502_25.991: the fit 0.641, its
# last step 1.12 px off centre; the wider band's circle 0.633, its last step 0.17 px off); the
# rims tell them apart at half a pixel (63 near against 89). On the 6 900 development frames of
# the ray-caster (seeds 418-429 and 432-441, rig-photo 501-503) 6 862 -> 6 869 circles within
# 0.5 px and 0.5 % (9 in, 2 out); with 0.3 inlier_px 6 869, by the rims' Tukey weights at the
# floor scale 6 868, by the support as before 6 862. A constant of the algorithm, not a model
# parameter; crop2.cpp has the same (rim_near).
RIM_NEAR = 0.5

# Fine stripes behind the sphere (blinds, a striped backdrop, shelves) give the coarse vote more
# edges than the sphere's rim, all of one orientation, and their votes add up along the stripes to
# peaks 25-60 px off the sphere. When the largest of 16 orientation bins (of the coarse edges'
# gradients, modulo 180 degrees, pi/16 wide and centred on multiples of pi/16, so that stripes
# along the axes or the diagonals fall in the middle of one) holds at least STRIPE_SHARE of the
# edges, the edges of every bin with more than STRIPE_DROP times the median bin's count are left
# out of the coarse stage (the vote and the radius vote; the fine stage sees the frame as it is).
# The bins are integer tests against ORIENT_SLOPES, 1000 tan((2k + 1) pi / 32) rounded, so that
# both languages bin alike. A sphere's rim has edges of every orientation in like numbers, so it
# keeps most of them (all but a dropped bin's); a frame with 9 or more empty bins (a median of 0)
# has no rim in it, and every edge of a non-empty bin is dropped: no sphere found. See
# docs/bench/localise.md for the measurement. Constants of the algorithm, not model
# parameters; crop2.cpp has the same (orient_slopes, stripe_share, stripe_drop).
ORIENT_SLOPES = (98, 303, 535, 821, 1219, 1871, 3297, 10153)
STRIPE_SHARE = 0.45
STRIPE_DROP = 3


class NoSphere(ValueError):
    """The frame holds nothing that looks like the sphere (or not one sphere, whole)."""


NO_SPHERE = "no sphere found in frame"


def params(overrides=None, model=None):
    """Preprocessing parameters: the defaults of the named algorithm (v2 unless overrides name
    another) updated by `overrides` (dict or JSON text). A v2 set must hold every v2 key.

    With `model` (the model's name, for messages), `overrides` is that model's
    `spherepose.preprocess` metadata and fills nothing: it must name its algorithm and hold
    every key of it and no other, else ValueError naming the key (as the C runtime refuses such
    a model); this project's exports always write every key."""
    if model is not None:
        return _model_params(overrides, model)
    o = (json.loads(overrides) if isinstance(overrides, str) else dict(overrides)) if overrides else {}
    name = o.get("name", NAME)
    if name == NAME_V1:
        p = dict(DEFAULTS_V1)
    elif name == NAME_V2:
        p = dict(DEFAULTS_V2)
    else:
        raise ValueError(f"unknown preprocessing {name!r}; this code implements {NAME_V1!r} and {NAME_V2!r}")
    p.update(o)
    return p


def _model_params(meta, model):
    where = f"{model}: metadata spherepose.preprocess"
    if meta is None:
        raise ValueError(f"{model}: missing metadata key spherepose.preprocess")
    try:
        o = json.loads(meta) if isinstance(meta, str) else dict(meta)
    except (ValueError, TypeError) as e:
        raise ValueError(f"{where}: not a JSON object ({e})") from None
    if not isinstance(o, dict):
        raise ValueError(f"{where}: not a JSON object")
    if "name" not in o:
        raise ValueError(f'{where}: needs key "name" (the model\'s export wrote no value for it)')
    defaults = {NAME_V1: DEFAULTS_V1, NAME_V2: DEFAULTS_V2}.get(o["name"])
    if defaults is None:
        raise ValueError(f"{where}: unknown preprocessing {o['name']!r}; this code implements "
                         f"{NAME_V1!r} and {NAME_V2!r}")
    for k in o:
        if k not in defaults:
            raise ValueError(f'{where}: unknown {o["name"]} key "{k}"')
    for k in defaults:
        if k not in o:
            raise ValueError(f'{where}: {o["name"]} needs key "{k}" (the model\'s export wrote no value for it)')
    return o


def _as_bgr(frame):
    if frame.ndim == 2:
        return cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    if frame.shape[2] == 4:
        return cv2.cvtColor(frame, cv2.COLOR_BGRA2BGR)
    return frame


# ---- camera ---------------------------------------------------------------------------------

def _cam_get(camera, key, default=None):
    if isinstance(camera, dict):
        return camera.get(key, default)
    return getattr(camera, key, default)


def camera_geometry(camera):
    """(expected radius px, fx, u0, v0, distortion or None) of a camera (sim.camera.Camera or a
    dict of camera-file keys); u0, v0 in OpenCV pixel coordinates (pixel centres at integers)."""
    from sim.camera import REFERENCE
    g = {k: float(_cam_get(camera, k, REFERENCE[k])) for k in REFERENCE}
    f = g["focal_mm"] / g["pixel_mm"]
    R, D = g["sphere_diameter_mm"] / 2.0, g["distance_mm"]
    r_px = f * R / math.sqrt(D * D - R * R)
    pp = _cam_get(camera, "principal_px", None)
    u0, v0 = (g["width"] / 2.0, g["height"] / 2.0) if pp is None else (float(pp[0]), float(pp[1]))
    dist = _cam_get(camera, "distortion", None)
    if dist is not None and not any(float(d) != 0.0 for d in dist):
        dist = None
    return r_px, f, u0 - 0.5, v0 - 0.5, (None if dist is None else [float(d) for d in dist])


def undistort(frame, camera):
    """The frame without the camera's lens distortion (OpenCV's model, same camera matrix in and
    out): output pixel (x, y) takes the distorted image at the model's point for it, bilinear with
    weights in 1/32 steps (as cv2.remap's fixed point), outside the frame 0. Unchanged when the
    camera has no distortion. Written out (not cv2.undistort) so that C++ gives the same bytes."""
    frame = _as_bgr(frame)
    _, f, cx, cy, dist = camera_geometry(camera)
    if dist is None:
        return frame
    _check_size(frame, camera)
    h, w = frame.shape[:2]
    mx, my = _undistort_map(w, h, f, cx, cy, tuple(dist))
    return _remap_bilinear(frame, mx, my)


_MAP_CACHE = {}


def _undistort_map(w, h, f, cx, cy, dist):
    key = (w, h, f, cx, cy, dist)
    if key in _MAP_CACHE:
        return _MAP_CACHE[key]
    k1, k2, p1, p2, k3 = (list(dist) + [0.0] * 5)[:5]
    x = (np.arange(w, dtype=np.float64) - cx) / f
    y = (np.arange(h, dtype=np.float64) - cy) / f
    x, y = np.broadcast_to(x[None, :], (h, w)), np.broadcast_to(y[:, None], (h, w))
    x2, y2, xy = x * x, y * y, x * y
    r2 = x2 + y2
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + (2.0 * p1) * xy + p2 * (r2 + 2.0 * x2)
    yd = y * radial + p1 * (r2 + 2.0 * y2) + (2.0 * p2) * xy
    # source position in 1/32 pixel steps (as cv2.remap's INTER_LINEAR fixed point)
    mx = np.floor((f * xd + cx) * 32.0 + 0.5)
    my = np.floor((f * yd + cy) * 32.0 + 0.5)
    big = 32.0 * (1 << 24)
    mx = np.clip(mx, -big, big).astype(np.int64)
    my = np.clip(my, -big, big).astype(np.int64)
    if len(_MAP_CACHE) > 4:
        _MAP_CACHE.clear()
    _MAP_CACHE[key] = (mx, my)
    return mx, my


def _remap_bilinear(img, mx, my):
    h, w = img.shape[:2]
    x0, y0 = mx >> 5, my >> 5
    ax, ay = mx & 31, my & 31
    out = np.zeros((h, w, 3), np.int64)
    pad = np.zeros((h + 2, w + 2, 3), np.int64)
    pad[1:-1, 1:-1] = img
    # corners outside the frame read 0 (the padded ring), farther ones are clamped into the ring
    xa = np.clip(x0 + 1, 0, w + 1)
    xb = np.clip(x0 + 2, 0, w + 1)
    ya = np.clip(y0 + 1, 0, h + 1)
    yb = np.clip(y0 + 2, 0, h + 1)
    w00 = ((32 - ax) * (32 - ay))[..., None]
    w01 = (ax * (32 - ay))[..., None]
    w10 = ((32 - ax) * ay)[..., None]
    w11 = (ax * ay)[..., None]
    out = pad[ya, xa] * w00 + pad[ya, xb] * w01 + pad[yb, xa] * w10 + pad[yb, xb] * w11
    return ((out + 512) >> 10).astype(np.uint8)


# ---- sphere-crop-v1 -------------------------------------------------------------------------

def background_colour(frame, p):
    """Per-channel median of the border band (v1 step 1)."""
    h, w = frame.shape[:2]
    b = max(2, math.floor(p["border_frac"] * min(h, w) + 0.5))
    band = np.concatenate([
        frame[:b].reshape(-1, 3), frame[h - b:].reshape(-1, 3),
        frame[b:h - b, :b].reshape(-1, 3), frame[b:h - b, w - b:].reshape(-1, 3)])
    return np.median(band.astype(np.float64), axis=0)


def _find_sphere_v1(frame, p):
    h, w = frame.shape[:2]
    bg = background_colour(frame, p)
    # max over channels of |I_c - bg_c|, channel by channel (numpy's max over a length-3 last axis
    # is slow); float32 is exact here: I_c is an integer and bg_c an integer or a half
    f = frame.astype(np.float32)
    diff = np.abs(f[:, :, 0] - np.float32(bg[0]))
    for c in (1, 2):
        np.maximum(diff, np.abs(f[:, :, c] - np.float32(bg[c])), out=diff)
    mask = np.where(diff > p["fg_threshold"], 255, 0).astype(np.uint8)
    k = 2 * math.floor(p["close_frac"] * min(h, w) / 2) + 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, kernel)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    best, best_area = None, -1.0
    for c in contours:
        a = cv2.contourArea(c)
        if a > best_area:
            best, best_area = c, a
    if best is None or best_area < p["min_area_frac"] * h * w:
        raise NoSphere(NO_SPHERE)
    # the hull has the same enclosing circle as the contour, from a tenth of the points
    (cx, cy), r = cv2.minEnclosingCircle(cv2.convexHull(best))
    return cx, cy, r, bg


# ---- sphere-crop-v2: coarse stage -----------------------------------------------------------

def radius_range(h, w, p, camera=None):
    """(r_min, r_max) in pixels: from the camera's expected radius, or fractions of min(H, W)."""
    if camera is not None:
        r = camera_geometry(camera)[0]
        return r * (1.0 - p["r_tol"]), r * (1.0 + p["r_tol"])
    m = float(min(h, w))
    return p["r_min_frac"] * m, p["r_max_frac"] * m


def _reduce(frame, s):
    """Block means (rounded half up, integers) of s x s blocks, the remainder rows/columns dropped."""
    h, w = frame.shape[:2]
    hs, ws = h // s, w // s
    if s == 1:
        return frame.astype(np.int32)
    b = frame[:hs * s, :ws * s].astype(np.int32).reshape(hs, s, ws, s, 3).sum(axis=(1, 3))
    return (b + (s * s) // 2) // (s * s)


def _edges(red, edge_min):
    """Edge pixels of the reduced image: Sobel per channel, the channel of largest gx^2 + gy^2
    (first on ties), at least edge_min^2, kept where not below both neighbours across the edge.
    Returns x, y, gx, gy (int64 arrays, row-major order)."""
    hs, ws = red.shape[:2]
    g = red.astype(np.int64)
    gx = (g[:-2, 2:] + 2 * g[1:-1, 2:] + g[2:, 2:]) - (g[:-2, :-2] + 2 * g[1:-1, :-2] + g[2:, :-2])
    gy = (g[2:, :-2] + 2 * g[2:, 1:-1] + g[2:, 2:]) - (g[:-2, :-2] + 2 * g[:-2, 1:-1] + g[:-2, 2:])
    m2 = gx * gx + gy * gy
    best = np.zeros(m2.shape[:2], np.int64)
    for c in (1, 2):
        best = np.where(m2[:, :, c] > m2[np.arange(m2.shape[0])[:, None], np.arange(m2.shape[1])[None, :], best],
                        c, best)
    ii, jj = np.indices(best.shape)
    GX, GY, M2 = gx[ii, jj, best], gy[ii, jj, best], m2[ii, jj, best]
    # interior of the gradient image: (hs - 2) x (ws - 2), frame pixel (x, y) = (j + 1, i + 1).
    # Non-maximum suppression needs the neighbours: pad M2 with zeros.
    P = np.zeros((M2.shape[0] + 2, M2.shape[1] + 2), np.int64)
    P[1:-1, 1:-1] = M2
    ax, ay = np.abs(GX), np.abs(GY)
    horiz = 5 * ay <= 2 * ax
    vert = 5 * ax <= 2 * ay
    same = (GX > 0) == (GY > 0)
    c0 = P[1:-1, 1:-1]
    n_l, n_r = P[1:-1, :-2], P[1:-1, 2:]
    n_u, n_d = P[:-2, 1:-1], P[2:, 1:-1]
    n_ul, n_dr = P[:-2, :-2], P[2:, 2:]
    n_ur, n_dl = P[:-2, 2:], P[2:, :-2]
    a = np.where(horiz, n_l, np.where(vert, n_u, np.where(same, n_ul, n_ur)))
    b = np.where(horiz, n_r, np.where(vert, n_d, np.where(same, n_dr, n_dl)))
    keep = (M2 >= edge_min * edge_min) & (c0 >= a) & (c0 >= b)
    yi, xi = np.nonzero(keep)
    return xi + 1, yi + 1, GX[yi, xi], GY[yi, xi]


def _orientation_bins(gx, gy):
    """Bin 0..15 of each gradient's orientation modulo 180 degrees: bin k holds the angles within
    pi/32 of k pi/16 (integer tests against ORIENT_SLOPES, bin 8 for a zero gradient)."""
    flip = (gy < 0) | ((gy == 0) & (gx < 0))
    a, b = np.where(flip, -gx, gx), np.where(flip, -gy, gy)
    # b >= 0, the angle in [0, pi); q: how many bin edges in [0, pi/2] atan2(b, |a|) reaches
    q = np.zeros(a.shape, np.int64)
    for t in ORIENT_SLOPES:
        q += 1000 * b >= t * np.abs(a)
    return np.where(a < 0, (16 - q) % 16, q)


def _drop_stripes(x, y, gx, gy):
    """The coarse edges without those of an orientation that dominates them (see STRIPE_SHARE)."""
    if x.size == 0:
        return x, y, gx, gy
    k = _orientation_bins(gx, gy)
    cnt = np.bincount(k, minlength=16)
    if float(cnt.max()) < STRIPE_SHARE * float(x.size):
        return x, y, gx, gy
    mid = np.sort(cnt)[7:9].sum()  # twice the median of 16 counts
    keep = ~(2 * cnt > STRIPE_DROP * mid)[k]
    return x[keep], y[keep], gx[keep], gy[keep]


def _radius_bins(lo, hi, q):
    """Bin of each integer radius lo..hi (reduced pixels): bins about q * radius wide."""
    bins, start, b = [], lo, 0
    for rho in range(lo, hi + 1):
        if rho > start * (1.0 + q) and rho - start >= 2:
            b += 1
            start = rho
        bins.append(b)
    return bins


def _coarse(frame, p, rmin, rmax, gap_r=None):
    """Candidate circles [(cx, cy, r, votes)] in frame coordinates, strongest first, from the
    reduced image; the weaker peaks after them down to WEAK_PEAK of the best's votes (the same
    form); the scale s. Votes go to (centre, radius bin): a circle's edges agree on both, clutter's
    do not. A peak clears the centres within cand_gap times gap_r (rmin unless given; reduced
    pixels, rounded down as the radii are) around it (_find_sphere_v2 says why)."""
    h, w = frame.shape[:2]
    s = max(1, min(h, w) // p["coarse_size"])
    red = _reduce(frame, s)
    hs, ws = red.shape[:2]
    if hs < 8 or ws < 8:
        return [], [], s
    x, y, gx, gy = _drop_stripes(*_edges(red, p["edge_min"]))
    if x.size == 0:
        return [], [], s
    lo = max(1, math.floor(rmin / s))
    hi = math.floor(rmax / s) + 1
    if hi < lo:
        return [], [], s
    gap_lo = lo if gap_r is None else max(1, math.floor(gap_r / s))
    bins = _radius_bins(lo, hi, p["coarse_rbin"])
    nb = bins[-1] + 1
    rho = np.arange(lo, hi + 1, dtype=np.float64)
    rb = np.array(bins, np.int64)
    m = np.sqrt((gx * gx + gy * gy).astype(np.float64))
    ux, uy = gx / m, gy / m
    acc = np.zeros(nb * hs * ws, np.int64)
    for sign in (1.0, -1.0):
        X = np.floor(x[:, None] - sign * rho[None, :] * ux[:, None] + 0.5)
        Y = np.floor(y[:, None] - sign * rho[None, :] * uy[:, None] + 0.5)
        ok = (X >= 0) & (X < ws) & (Y >= 0) & (Y < hs)
        B = np.broadcast_to(rb[None, :], X.shape)
        idx = (B[ok] * hs + Y[ok].astype(np.int64)) * ws + X[ok].astype(np.int64)
        acc += np.bincount(idx, minlength=nb * hs * ws)
    acc = acc.reshape(nb, hs, ws)
    # 3 x 3 box sum per bin (zeros outside), then each bin with the next one (the same as the
    # box sum of each bin plus the next: integers)
    pair = acc.copy()
    pair[:-1] += acc[1:]
    P = np.zeros((nb, hs + 2, ws + 2), np.int64)
    P[:, 1:-1, 1:-1] = pair
    hsum = P[:, :, :-2] + P[:, :, 1:-1] + P[:, :, 2:]
    work = hsum[:, :-2] + hsum[:, 1:-1] + hsum[:, 2:]
    # per centre its best radius bin (first on ties); peaks in row-major order (first on ties)
    vmax = work.max(axis=0)
    bmax = work.argmax(axis=0)
    cands, weak = [], []
    sup = p["cand_gap"] * gap_lo
    yy, xx = np.indices((hs, ws))
    best = None
    start = [bins.index(b) + lo for b in range(nb)] + [hi + 1]
    # a peak whose circle would be refused as cut by the frame edge is refined but does not use
    # up one of the `candidates` places: without a camera file the radius search is wide, and the
    # texture's own arcs can add up to large circles mostly outside the frame that would take
    # every place (at most 4 x candidates peaks in all, the weaker ones after them included)
    taken = 0
    for _ in range(4 * p["candidates"]):
        if taken >= p["candidates"]:
            break
        k = int(np.argmax(vmax))
        v = int(vmax.flat[k])
        if v <= 0 or (best is not None and v < min(WEAK_PEAK, p["cand_frac"]) * best):
            break
        best = v if best is None else best
        strong = v >= p["cand_frac"] * best
        Yc, Xc = divmod(k, ws)
        b = int(bmax[Yc, Xc])
        r_s = _radius_vote(x, y, gx, gy, Xc, Yc, start[b], start[min(b + 2, nb)] - 1)
        if r_s is not None:
            off = (s - 1) / 2.0
            (cands if strong else weak).append((Xc * s + off, Yc * s + off, r_s * s, v))
        if strong and (r_s is None
                       or rim_outside(Xc * s + off, Yc * s + off, r_s * s, h, w) <= p["max_cut"]):
            taken += 1
        # suppress this peak's neighbourhood (centres closer than cand_gap times gap_lo)
        d2 = (xx - Xc) ** 2 + (yy - Yc) ** 2
        vmax[d2 <= sup * sup] = 0
    return cands, weak, s


def _radius_vote(x, y, gx, gy, Xc, Yc, lo, hi):
    """Radius (reduced pixels) around centre (Xc, Yc): histogram of the distances of the edge
    pixels whose gradient points along the radius (within about 25 degrees), smoothed 1-2-1."""
    dx, dy = x - Xc, y - Yc
    d2 = dx * dx + dy * dy
    dot = dx * gx + dy * gy
    m2 = gx * gx + gy * gy
    radial = 100 * dot * dot >= 81 * d2 * m2
    b = np.floor(np.sqrt(d2[radial].astype(np.float64)) + 0.5).astype(np.int64)
    b = b[(b >= lo) & (b <= hi)]
    if b.size == 0:
        return None
    hist = np.bincount(b - lo, minlength=hi - lo + 1)
    hp = np.concatenate([[0], hist, [0]])
    sm = hp[:-2] + 2 * hp[1:-1] + hp[2:]
    i = int(np.argmax(sm))
    return float(lo + i)


# ---- sphere-crop-v2: fine stage -------------------------------------------------------------

def _ray_dirs(k):
    """Unit directions of k rays (k a multiple of 8), angle 2 pi i / k, from a Taylor series
    (the same float64 operations in C++; no libm)."""
    q = k // 8
    base = []
    for i in range(q + 1):
        t = (math.pi / 4) * i / q  # pi/4 * i / q, in [0, pi/4]
        t2 = t * t
        c, s_ = 1.0, t
        term_c, term_s = 1.0, t
        for n in range(1, 12):
            term_c = -term_c * t2 / ((2 * n - 1) * (2 * n))
            term_s = -term_s * t2 / ((2 * n) * (2 * n + 1))
            c += term_c
            s_ += term_s
        base.append((c, s_))
    dirs = []
    for i in range(k):
        octant, j = divmod(i, q)
        if octant % 2 == 0:
            c, s_ = base[j]
        else:
            s_, c = base[q - j]
        # rotate the first-quadrant pair into its quadrant (exact sign flips and swaps)
        quad = octant // 2
        if quad == 0:
            dirs.append((c, s_))
        elif quad == 1:
            dirs.append((-s_, c))
        elif quad == 2:
            dirs.append((-c, -s_))
        else:
            dirs.append((s_, -c))
    return np.array(dirs, np.float64)


def _sample(img, X, Y):
    """Bilinear samples [..., 3] (float64) of img at (X, Y); NaN where a corner lies outside."""
    h, w = img.shape[:2]
    x0, y0 = np.floor(X), np.floor(Y)
    fx, fy = X - x0, Y - y0
    ok = (x0 >= 0) & (y0 >= 0) & (x0 <= w - 2) & (y0 <= h - 2)
    xi = np.where(ok, x0, 0).astype(np.int64)
    yi = np.where(ok, y0, 0).astype(np.int64)
    p00 = img[yi, xi].astype(np.float64)
    p01 = img[yi, xi + 1].astype(np.float64)
    p10 = img[yi + 1, xi].astype(np.float64)
    p11 = img[yi + 1, xi + 1].astype(np.float64)
    fx, fy = fx[..., None], fy[..., None]
    top = p00 + fx * (p01 - p00)
    bot = p10 + fx * (p11 - p10)
    v = top + fy * (bot - top)
    v[~ok] = np.nan
    return v


def _ray_scores(img, dirs, cx, cy, r, win):
    """The colour step along each ray from (cx, cy) (max over channels of |difference of the
    samples 1 px apart|, samples every half pixel) within [r - win, r + win]: (rho [n + 2] of the
    samples, score [K, n] centred on samples 0..n-1 (rho[1:-1]), bad [K]: the ray leaves the
    frame)."""
    m = int(math.floor(win * 2.0))
    n = 2 * m + 1
    j = np.arange(-1, n + 1, dtype=np.float64)  # one extra sample each side for the differences
    rho = r + (j - m) * 0.5
    X = cx + rho[None, :] * dirs[:, 0:1]
    Y = cy + rho[None, :] * dirs[:, 1:2]
    v = _sample(img, X, Y)  # [K, n + 2, 3]
    d = np.abs(v[:, 2:, :] - v[:, :-2, :])  # [K, n, 3], centred on samples 0..n-1
    score = np.maximum(np.maximum(d[:, :, 0], d[:, :, 1]), d[:, :, 2])
    bad = np.isnan(score).any(axis=1)
    score = np.where(np.isnan(score), 0.0, score)
    return rho, score, bad


def _peaks(rho, score, thr):
    """Local maxima (at least thr) of the scores, at samples 1..n-2: (mask [K, n-2], sub-pixel
    position [K, n-2] (parabola))."""
    c, a_, b_ = score[:, 1:-1], score[:, :-2], score[:, 2:]
    peak = (c >= thr) & (c >= a_) & (c > b_)
    den = a_ - 2.0 * c + b_
    off = np.where(den < 0.0, 0.5 * (a_ - b_) / np.where(den < 0.0, den, -1.0), 0.0)
    return peak, rho[None, 2:-2] + off * 0.5


def _ray_edges(img, dirs, cx, cy, r, win, p, ratio=0.0):
    """Edge candidates along each ray from (cx, cy): the local maxima, of at least ray_edge_min,
    of the colour step (see _ray_scores) within [r - win, r + win], sub-pixel (parabola); with a
    ratio, only those of at least ratio times the median step of their ray. Returns a list per
    ray of distances from (cx, cy); None for a ray that leaves the frame."""
    rho, score, bad = _ray_scores(img, dirs, cx, cy, r, win)
    peak, pos = _peaks(rho, score, p["ray_edge_min"])
    if ratio > 0.0:
        srt = np.sort(score, axis=1)
        n = srt.shape[1]
        med = (srt[:, (n - 1) // 2] + srt[:, n // 2]) / 2.0
        peak &= score[:, 1:-1] >= ratio * med[:, None]
    return [None if bad[k] else pos[k][peak[k]].tolist() for k in range(len(dirs))]


def _seqsum(a):
    """Sum in index order (as a C loop), not numpy's pairwise order."""
    t = 0.0
    for v in a:
        t += v
    return t


def _median(vals):
    s = sorted(vals)
    n = len(s)
    return (s[(n - 1) // 2] + s[n // 2]) / 2.0


def _kasa(x, y, wts):
    """Weighted algebraic circle fit of x^2 + y^2 = A x + B y + C: (cx, cy, r) or None."""
    sw = sxx = syy = sxy = sx = sy = sxz = syz = sz = 0.0
    for i in range(len(x)):
        wi = wts[i]
        if wi == 0.0:
            continue
        xi, yi = x[i], y[i]
        zi = xi * xi + yi * yi
        sw += wi
        sx += wi * xi
        sy += wi * yi
        sxx += wi * xi * xi
        syy += wi * yi * yi
        sxy += wi * xi * yi
        sxz += wi * xi * zi
        syz += wi * yi * zi
        sz += wi * zi
    sol = _solve3([[sxx, sxy, sx], [sxy, syy, sy], [sx, sy, sw]], [sxz, syz, sz])
    if sol is None:
        return None
    A, B, C = sol
    cx, cy = A / 2.0, B / 2.0
    rr = C + cx * cx + cy * cy
    if not rr > 0.0:
        return None
    return cx, cy, math.sqrt(rr)


def _biweight(res, cut):
    """Tukey's biweight of the residuals res, zero from |residual| = cut on."""
    u = np.asarray(res, dtype=np.float64) / cut
    return np.where((-1.0 < u) & (u < 1.0), (1.0 - u * u) * (1.0 - u * u), 0.0).tolist()


def _tukey_weights(res, p):
    """The robust fit's weights of its residuals: Tukey's biweight at tukey_c times the scale
    (1.4826 times the median |residual|, at least sigma_min_px)."""
    sigma = max(p["sigma_min_px"], 1.4826 * _median([abs(v) for v in res]))
    return _biweight(res, p["tukey_c"] * sigma)


def _tukey_floor_weights(res, p):
    """Tukey's biweight at tukey_c times the floor of the robust scale (sigma_min_px), for the
    refit's last round (_outermost)."""
    return _biweight(res, p["tukey_c"] * p["sigma_min_px"])


def _fit_rays(cands, dirs, ox, oy, cx, cy, r, p):
    """Robust circle through one edge candidate per ray: each iteration takes, on every ray, the
    candidate nearest the current circle, weights it by Tukey's biweight of its distance to that
    circle (scale from the median distance) and refits (algebraic fit, coordinates about the ray
    origin (ox, oy)). Returns (cx, cy, r, residuals of the chosen points) or None."""
    cx, cy = cx - ox, cy - oy
    # candidates as a [rays with candidates, most candidates] array, NaN-padded
    rows = [k for k in range(len(dirs)) if cands[k]]
    if len(rows) < 8:
        return None
    width = max(len(cands[k]) for k in rows)
    rho = np.full((len(rows), width), np.nan)
    for i, k in enumerate(rows):
        rho[i, :len(cands[k])] = cands[k]
    ux, uy = dirs[rows, 0][:, None], dirs[rows, 1][:, None]
    px, py = rho * ux, rho * uy
    res = []
    for it in range(p["irls_iters"]):
        # on each ray the candidate nearest the circle (first on ties)
        e = np.sqrt((px - cx) * (px - cx) + (py - cy) * (py - cy)) - r
        ae = np.where(np.isnan(e), np.inf, np.abs(e))
        j = np.argmin(ae, axis=1)
        idx = np.arange(len(rows))
        best = rho[idx, j]
        res = e[idx, j].tolist()
        xs = (best * ux[:, 0]).tolist()
        ys = (best * uy[:, 0]).tolist()
        fit = _kasa(xs, ys, _tukey_weights(res, p))
        if fit is None:
            return None
        cx, cy, r = fit
    return cx + ox, cy + oy, r, res


def _solve3(M, v):
    """Cramer's rule for a 3 x 3 system (fixed operation order); None when singular."""
    (a, b, c), (d, e, f), (g, h, i) = M
    co0 = e * i - f * h
    co1 = f * g - d * i
    co2 = d * h - e * g
    det = a * co0 + b * co1 + c * co2
    if not abs(det) > 1e-300:
        return None
    p_, q, r_ = v
    x0 = (p_ * co0 + b * (f * r_ - q * i) + c * (q * h - e * r_)) / det
    x1 = (a * (q * i - f * r_) + p_ * co1 + c * (d * r_ - q * g)) / det
    x2 = (a * (e * r_ - q * h) + b * (q * g - d * r_) + p_ * co2) / det
    return x0, x1, x2


def _consensus(cands, dirs, r, win, step):
    """The circle most rays agree on, near the rays' origin: for each centre shift (dx, dy) on a
    grid of `step` px within +-win, each ray's edge candidates give radii rho - (dx, dy) . u (to
    first order); the (shift, radius bin of `step` px) reached by the most rays wins (first in
    grid order, then bin order, on ties). A ray counts once per bin however many of its
    candidates fall in it: on a busy backdrop (a checkerboard, noise) a few rays with many
    candidates would otherwise outvote the rim. Returns (dx, dy, r) or None."""
    W = int(math.floor(win / step))
    base = r - (W * step + win) - step
    nb = int(math.floor(2.0 * (W * step + win) / step)) + 3
    ks = [k for k in range(len(dirs)) for _ in (cands[k] or ())]
    if not ks:
        return None
    rho = np.array([c for k in range(len(dirs)) for c in (cands[k] or ())], np.float64)
    ux, uy = dirs[ks, 0], dirs[ks, 1]
    g = np.arange(-W, W + 1, dtype=np.float64) * step
    DY, DX = np.meshgrid(g, g, indexing="ij")
    dot = DX.reshape(-1, 1) * ux[None, :] + DY.reshape(-1, 1) * uy[None, :]
    bi = np.floor(((rho[None, :] - dot) - base) / step).astype(np.int64)
    ok = (bi >= 0) & (bi < nb)
    G, K = dot.shape[0], len(dirs)
    flat = (np.arange(G)[:, None] * nb + bi)[ok]
    ray = np.broadcast_to(np.asarray(ks, np.int64)[None, :], bi.shape)[ok]
    # one count per (shift, bin, ray)
    hist = np.bincount(np.unique(flat * K + ray) // K, minlength=G * nb)
    i = int(np.argmax(hist))
    if hist[i] <= 0:
        return None
    gi, b_ = divmod(i, nb)
    dy, dx = divmod(gi, 2 * W + 1)
    return (dx - W) * step, (dy - W) * step, base + (b_ + 0.5) * step


def _fine(img, dirs, cand, s, p):
    """Refine a coarse circle: (cx, cy, r, support) or None (see _support)."""
    cx, cy, r = cand[:3]
    for ps in range(p["fine_passes"]):
        if ps == 0:
            # the shift grid covers the coarse centre's error; the rays reach farther, for the
            # radius's error on top of it
            win = p["consensus_cells"] * s + p["consensus_px"]
            cands = _ray_edges(img, dirs, cx, cy, r, p["consensus_reach"] * win, p,
                               p["consensus_edge_ratio"])
        else:
            win = p["fine_window_px"] + p["fine_window_frac"] * r
            cands = _ray_edges(img, dirs, cx, cy, r, win, p)
        sx, sy, sr = cx, cy, r
        if ps == 0:
            c = _consensus(cands, dirs, r, win, p["consensus_step_px"])
            if c is None:
                return None
            sx, sy, sr = cx + c[0], cy + c[1], c[2]
        fit = _fit_rays(cands, dirs, cx, cy, sx, sy, sr, p)
        if fit is None or not fit[2] > 1.0:
            return None
        cx, cy, r, _ = fit
    return cx, cy, r, _support(img, dirs, cx, cy, r, p)


def _passes(img, dirs, cx, cy, r, p):
    """fine_passes - 1 passes, as after the first, from the circle (cx, cy, r): the circle they
    reach, or None when a fit fails (crop2.cpp passes_from)."""
    for _ in range(p["fine_passes"] - 1):
        win = p["fine_window_px"] + p["fine_window_frac"] * r
        f = _fit_rays(_ray_edges(img, dirs, cx, cy, r, win, p), dirs, cx, cy, cx, cy, r, p)
        if f is None or not f[2] > 1.0:
            return None
        cx, cy, r, _ = f
    return cx, cy, r


def _grow(img, dirs, fit, p, inward=False):
    """A weakly supported fit tried again from larger circles: where the limb is dark against a
    dark backdrop, the fit can settle on a black texture band just inside it (a circle 2-5 %
    small, off towards the bright side), whose edges are stronger than the rim's. From the same
    centre with the radius fine_window_px and 2 fine_window_px larger, fine_passes - 1 passes
    (as after the first) each; the best supported of the fit and these (the fit on ties) is
    kept. Inward (a fit that was no sphere at all, see _search): then also from the
    radius fine_window_px and 2 fine_window_px smaller (after the larger ones; the first on
    ties): where the backdrop's noise or clutter makes edges all along the rays, the fit can
    settle a few pixels outside the rim on one side, farther from the rim's edges than the
    passes' window reaches. Returns (cx, cy, r, support)."""
    best = fit
    for k in (1, 2, -1, -2) if inward else (1, 2):
        c = _passes(img, dirs, fit[0], fit[1], fit[2] + k * p["fine_window_px"], p)
        if c is None:
            continue
        cx, cy, r = c
        sup = _support(img, dirs, cx, cy, r, p)
        if sup > best[3]:
            best = (cx, cy, r, sup)
    return best


def _decisive_support(p):
    """A support that settles a fit, halfway from min_support to every ray: a weaker fit is tried
    again (_grown, _grow_first, _tangent), and a coarse peak whose centre lies inside a fit this
    well supported is not refined."""
    return (1.0 + p["min_support"]) / 2.0


def _grown(img, dirs, fit, p, inward, until):
    """fit tried from _grow's circles again and again: from the circle it moved to, while that is
    better supported and still below `until`, at most GROW_ROUNDS tries. Returns the last fit."""
    for _ in range(GROW_ROUNDS):
        if fit[3] >= until:
            break
        g = _grow(img, dirs, fit, p, inward)
        if g is fit:
            break
        fit = g
    return fit


def _grow_first(img, dirs, fits, ib, p):
    """The first fit (of the strongest coarse peak that gave one) tried again as the best
    supported one is (_grown), in place in fits, when it is not that one (index ib, after its
    tries), its support is below (1 + min_support) / 2, the best one has at least min_support
    and holds its centre. A weaker peak's fit through part of the rim and the texture inside can
    be better supported than the sphere's own weak fit before its tries (rig s403
    26.641_-7.408_20.003, a dark limb on a dark gradient: 0.484 against 0.469, 8.6 px off; the
    first fit grown 0.664, 0.17 px). Not when the best has less than min_support (no sphere): in
    frames without one, a circle grown there was named as a cut sphere."""
    decisive = _decisive_support(p)
    f0, fb = fits[0], fits[ib]
    dx, dy = f0[0] - fb[0], f0[1] - fb[1]
    if ib != 0 and f0[3] < decisive and fb[3] >= p["min_support"] and dx * dx + dy * dy < fb[2] * fb[2]:
        fits[0] = _grown(img, dirs, f0, p, f0[3] < p["min_support"], decisive)


def _rescue(img, dirs, fit, p):
    """The best supported fit, when its support is from SECOND_RETRY (the same floor as a second
    circle's retries) to below min_support after its tries from larger and smaller circles,
    tried from the circles tangent to it on its supported arc (_tangent); the circle reached
    replaces it only when it reaches min_support and its inside is shaded as a lit sphere's
    (_limb_shading at least LIMB_MIN), else the fit is returned as it is. A sphere cut a few per
    cent by the frame edge, with a dark limb over much of the rest of its rim, loses those rays'
    support to the edge and the fine passes settle on the bands inside the dark arc (`edge`
    s406 29.959_-10.487_-24.61: the fit 0.34 against the true circle's 0.54): the frame was
    refused as without a sphere. The tangent circles reach it (0.52, 0.29 px off centre). On
    the 7 100 development frames (with the spent held-out seeds 410-413) 4 such frames are
    answered within the limits; without the shading test a `none` frame to refuse (s413, a
    clutter disk, shading 1.22) was answered too; with it, none. When the tangent circles stay
    below min_support, the circle they reached is refitted through the outermost edges of a
    wider band (_wide; kept when better supported, where the sphere's is judged by its rims:
    _final_circle): a dark limb over part of the
    rim can hold the passes on a band 1-2 px inside it, and the tangent circles slide back there
    (`rig` s423 6.002_0.21_8.019, a grey-blue gradient: the fit 0.383, refitted 0.531, the
    answer 0.10 px off centre; `edge` s422 -0.345_13.951_1.224, 12 % cut by the frame's top:
    0.383, refitted 0.461; 0.53 px off). On 3 800 development frames (the ray-caster's seeds
    418-425, two-edge 500-502, rig-photo 501-503) those two are answered and nothing else
    changes; on 1 600 fresh held-out frames (seeds 426-429) nothing changes. Returns (cx, cy, r,
    support)."""
    if not SECOND_RETRY <= fit[3] < p["min_support"]:
        return fit
    t = _tangent(img, dirs, fit, p)
    if not t[3] >= p["min_support"]:
        # and refitted through the outermost edges of a wider band (_wide)
        t = _wide(img, dirs, t, *_refit_rays(img, dirs, t, p), p)
    return t if _lit_sphere(img, dirs, t, p) else fit


def _lit_sphere(img, dirs, c, p):
    """Whether a circle reached by a refused frame's tries may replace its fit (_rescue,
    _retry_rest), or be the sphere of the second search (_find_sphere_v2): supported by at least
    min_support and its inside shaded as a lit sphere's (_limb_shading at least LIMB_MIN)."""
    if not c[3] >= p["min_support"]:
        return False
    s = _limb_shading(img, dirs, c[0], c[1], c[2], p)
    return s is not None and s >= LIMB_MIN


def _retry_rest(img, dirs, fits, ib, p, rmin, rmax):
    """When the best supported fit (index ib) is still below min_support after its tries and
    _rescue (the frame would be refused), every other fit of the sphere's size supported by at
    least SECOND_RETRY is tried as the best was (_grown from larger and smaller circles until
    (1 + min_support) / 2, then _rescue), in place in fits; the circle reached replaces the fit
    only when it reaches min_support and its inside is shaded as a lit sphere's (_limb_shading at
    least LIMB_MIN, as in _rescue). Over a dark limb on a dark backdrop, the strongest coarse
    peak's fit can lie on the texture bands just inside the limb. A weaker peak's fit, a smaller
    circle well inside the sphere, can then be a few rays better supported. Only that one was
    tried again, and the frame was refused (rig-unseen s432 18.762_17.908_-4.206: the first fit
    0.336, the smaller circle's 0.344; the first fit grown 0.805, the answer 0.03 px off
    centre)."""
    if fits[ib][3] >= p["min_support"]:
        return
    decisive = _decisive_support(p)
    for i, f in enumerate(fits):
        if i == ib or not SECOND_RETRY <= f[3] < p["min_support"] or not _sized(f[2], rmin, rmax):
            continue
        g = _rescue(img, dirs, _grown(img, dirs, f, p, True, decisive), p)
        if _lit_sphere(img, dirs, g, p):
            fits[i] = g


def _outermost(rays, peaks, dirs, fit, p, out=2.0):
    """The sphere refitted through the outermost edges near it: on an arc where the limb and the
    backdrop have nearly the same colour, the rays find only a texture band or the limb's shading
    1.5-2.5 px inside the rim, and the fit through the candidates nearest it leans towards them;
    the rim is the sphere's outermost edge. rays: _ray_scores of the support's rays from its
    centre (within +-support_flank_px, no rays cast again); peaks: their edge candidates
    (_peaks at ray_edge_min, shared with _rim). One robust fit (irls_iters rounds, as every pass) through, on each ray, the
    outermost candidate from 1.5 inlier_px inside the current circle to `out` inlier_px outside
    (farther out, a post or the backdrop's clutter), taken at the first round and once more
    after half the rounds, about the circle the fit has reached then (a circle pulled inwards
    by the bands reaches the rim beyond the first band's reach; taken every round or every
    other round, it creeps out onto the backdrop's edges). The last round weighs the residuals
    at the floor of the robust scale (sigma_min_px, _tukey_floor_weights): where the limb darkens
    to the backdrop's level on an arc, about a third of the rays find only its shading 1-3 px
    inside the rim; they widen the median-based scale enough to keep their weight, and the circle
    leans inwards on that arc (0.5-0.9 px off centre on the ray-caster's rig frames). By then
    the circle lies within the edges' noise of the rays that find the rim, so at the floor scale
    those 1.2 px (tukey_c sigma_min_px) or more inside it drop out; fewer than 8 rays left: the
    previous round's circle. Returns (cx, cy, r), the circle unchanged when the refit fails."""
    cx, cy, r = fit[0], fit[1], fit[2]
    bad = rays[2]
    peak, pos = peaks
    cands = [[] if bad[k] else pos[k][peak[k]].tolist() for k in range(len(dirs))]
    lo, hi = -1.5 * p["inlier_px"], out * p["inlier_px"]
    x, y, nr = 0.0, 0.0, r  # the circle about the rays' origin (cx, cy)
    for it in range(p["irls_iters"]):
        res = []
        if it == 0 or it == p["irls_iters"] // 2:
            # on each ray the outermost candidate within the band about the current circle
            xs, ys = [], []
            for k in range(len(dirs)):
                ux, uy = dirs[k, 0], dirs[k, 1]
                sel = None
                for c in cands[k]:
                    px, py = c * ux - x, c * uy - y
                    e = math.sqrt(px * px + py * py) - nr
                    if lo <= e <= hi:
                        sel = (c * ux, c * uy, e)
                if sel is not None:
                    xs.append(sel[0])
                    ys.append(sel[1])
                    res.append(sel[2])
            if len(xs) < 8:
                return cx, cy, r
        else:
            for px, py in zip(xs, ys):
                px, py = px - x, py - y
                res.append(math.sqrt(px * px + py * py) - nr)
        if it == p["irls_iters"] - 1:
            # the last round at the floor scale: the circle now lies within the edges' noise
            # of the rays that find the rim, so a ray whose candidate is the limb's shading or a
            # band 1.2 px (tukey_c sigma_min_px) or more inside it drops out instead of pulling
            # the circle inwards; fewer than 8 rays left: the previous round's circle
            wts = _tukey_floor_weights(res, p)
            if sum(1 for v in wts if v > 0.0) < 8:
                break
        else:
            wts = _tukey_weights(res, p)
        f = _kasa(xs, ys, wts)
        if f is None:
            return cx, cy, r
        x, y, nr = f
    if not nr > 1.0:
        return cx, cy, r
    return cx + x, cy + y, nr


def _rim(rays, peaks, dirs, fit, new, p, cov=None):
    """The refitted circle `new` moved to the rim, from its steepest colour steps: where the limb
    darkens towards the rim (shading, under blur and anti-aliasing), the largest step along a ray
    lies up to a pixel inside the outline, while the step's outer flank stays anchored to it.
    rays: _ray_scores of the support's rays from the centre of `fit` (the circle before the refit;
    the same rays and peaks as _outermost's). On each, the step peak nearest the new circle
    (within inlier_px of where the ray crosses it, at least ray_edge_min, first on ties) gives its
    outer half-maximum (the first place outwards where the step falls to half the peak sample's);
    less the frame's edge half-width (the middle one of those half-maxima's distances from their
    peaks), that is the rim on the ray. The radius moves by the median of the rims' distances
    from the new circle, and the circle is then refitted through the rims (_through_rims, at the
    floor of the robust scale: a rim 1.2 px or more off the circle drops out). Where the limb
    darkens to the backdrop's level on an arc, the steps found there lie inside the rim and the
    centre fitted through them leans away from that arc; the rims do not (measured in
    docs/bench/localise.md, "The circle refitted through the rims"). Fewer than 8 rims: the new
    circle unchanged. Returns ((cx, cy, r), near): near, how many rims lie within RIM_NEAR
    inlier_px of that circle (0 with fewer than 8), judges it against another (_final_circle). A
    list `cov` gets the refitted centre's covariance from the rims (_centre_covariance), when
    there is one."""
    nx, ny, nr = new
    rims = _rims(rays, peaks, dirs, fit, new, p)
    if rims is None:
        return (nx, ny, nr), 0
    xs, ys, r0 = rims
    x, y, r = _through_rims(xs, ys, r0, p)
    if cov is not None:
        v = _centre_covariance(xs, ys, x, y, r, p)
        if v is not None:
            cov.extend(v)
    tol = RIM_NEAR * p["inlier_px"]
    near = sum(1 for ex, ey in zip(xs, ys)
               if abs(math.sqrt((ex - x) * (ex - x) + (ey - y) * (ey - y)) - r) <= tol)
    return (nx + x, ny + y, r), near


def _rims(rays, peaks, dirs, fit, new, p):
    """The rims of _rim, about the centre of circle `new`: (xs, ys, the new radius moved by the
    median of their distances from it), or None with fewer than 8."""
    cx, cy = fit[0], fit[1]
    nx, ny, nr = new
    rho, score, bad = rays
    peak, pos = peaks
    n = score.shape[1]
    dx, dy = nx - cx, ny - cy
    outer, width = [None] * len(dirs), []
    for k in range(len(dirs)):
        if bad[k]:
            continue
        # where the ray crosses the new circle
        du = dx * dirs[k, 0] + dy * dirs[k, 1]
        q = du * du - (dx * dx + dy * dy) + nr * nr
        if not q >= 0.0:
            continue
        t = du + math.sqrt(q)
        best, be = -1, 0.0
        for i in range(1, n - 1):
            if peak[k, i - 1]:
                e = abs(pos[k, i - 1] - t)
                if e <= p["inlier_px"] and (best < 0 or e < be):
                    best, be = i, e
        if best < 0:
            continue
        sc = score[k]
        h = sc[best] / 2.0
        j = best
        while j + 1 < n and sc[j + 1] > h:
            j += 1
        if j + 1 >= n:
            continue
        o = rho[j + 1] + (sc[j] - h) / (sc[j] - sc[j + 1]) * 0.5
        outer[k] = o
        width.append(o - pos[k, best - 1])
    if len(width) < 8:
        return None
    hw = sorted(width)[(len(width) - 1) // 2]
    xs, ys, off = [], [], []  # the rims about the new centre, and their distances from the circle
    for k in range(len(dirs)):
        if outer[k] is not None:
            ex = cx + (outer[k] - hw) * dirs[k, 0] - nx
            ey = cy + (outer[k] - hw) * dirs[k, 1] - ny
            xs.append(ex)
            ys.append(ey)
            off.append(math.sqrt(ex * ex + ey * ey) - nr)
    return xs, ys, nr + _median(off)


def _centre_covariance(xs, ys, x, y, r, p):
    """The covariance of the centre of circle (x, y, r) fitted through the rims (xs, ys) (_rim's
    refit, _through_rims): s2 times the centre's block of (J^T W J)^-1. J holds each rim's
    residual's derivatives by x, y and r, W the refit's weights about the circle (Tukey at the
    floor of the robust scale), s2 the weighted mean square residual over sum(W) - 3. Where rims
    are missing on two opposite arcs (a sphere past the frame's edge above, the post below), the
    centre is held loosely along that axis, and the covariance says so. Returns (cxx, cxy, cyy), or
    None with fewer than 8 rims of weight or no inverse."""
    dist = [math.sqrt((ex - x) * (ex - x) + (ey - y) * (ey - y)) for ex, ey in zip(xs, ys)]
    res = [d - r for d in dist]
    wts = _tukey_floor_weights(res, p)
    a00 = a01 = a02 = a11 = a12 = sw = sq = 0.0
    used = 0
    for i in range(len(xs)):
        wi = wts[i]
        if wi == 0.0:
            continue
        used += 1
        jx, jy = -(xs[i] - x) / dist[i], -(ys[i] - y) / dist[i]  # and -1 by r
        a00 += wi * jx * jx
        a01 += wi * jx * jy
        a02 -= wi * jx
        a11 += wi * jy * jy
        a12 -= wi * jy
        sw += wi
        sq += wi * res[i] * res[i]
    if used < 8 or not sw > 3.0:
        return None
    c00 = a11 * sw - a12 * a12
    c01 = a02 * a12 - a01 * sw
    c11 = a00 * sw - a02 * a02
    det = a00 * c00 + a01 * c01 + a02 * (a01 * a12 - a11 * a02)
    if not det > 0.0:
        return None
    s2 = sq / (sw - 3.0)
    return s2 * c00 / det, s2 * c01 / det, s2 * c11 / det


def _through_rims(xs, ys, r, p):
    """The circle through the rims (xs, ys) (_rim), from the circle of radius r about their
    origin: irls_iters rounds of Tukey weights at the floor of the robust scale and the algebraic
    fit, each from the last; a round with fewer than 8 rims of weight, or whose fit fails, ends it
    with the circle before. Returns (x, y, r) about the origin."""
    x, y = 0.0, 0.0
    for it in range(p["irls_iters"]):
        res = [math.sqrt((ex - x) * (ex - x) + (ey - y) * (ey - y)) - r for ex, ey in zip(xs, ys)]
        wts = _tukey_floor_weights(res, p)
        if sum(1 for v in wts if v > 0.0) < 8:
            break
        f = _kasa(xs, ys, wts)
        if f is None:
            break
        x, y, r = f
    return x, y, r


def _row_medians(a):
    """The median of each row of a (the mean of its two middle values)."""
    a = np.sort(a, axis=1)
    n = a.shape[1]
    return (a[:, (n - 1) // 2] + a[:, n // 2]) / 2.0


def _support_rays(img, dirs, cx, cy, r, p):
    """Which of the rays from (cx, cy) support the circle of radius r (see _support): a bool per
    ray."""
    rho, score, bad = _ray_scores(img, dirs, cx, cy, r, p["support_flank_px"])
    peak, pos = _peaks(rho, score, p["support_edge_min"])
    d = rho[1:-1] - r
    flank = np.abs(d) >= 2.0 * p["inlier_px"]
    inner = flank & (d < 0.0)
    outer = flank & ~inner  # a sample at r itself (inlier_px 0) outside, as crop2.cpp counts it
    if not inner.any() or not outer.any():
        return np.zeros(len(dirs), bool)
    med, med_in, med_out = (_row_medians(score[:, m]) for m in (flank, inner, outer))
    busy = np.where(med_in <= med_out, score[:, outer].max(axis=1), score[:, inner].max(axis=1))
    ratio, step = p["support_ratio"], score[:, 1:-1]
    clear = (step >= ratio * med[:, None]) | ((step >= ratio * np.minimum(med_in, med_out)[:, None]) &
                                              (step >= busy[:, None]))
    ok = peak & (np.abs(pos - r) <= p["inlier_px"]) & clear
    return ok.any(axis=1) & ~bad


def _support(img, dirs, cx, cy, r, p):
    """Fraction of all rays from (cx, cy) whose colour step has a local maximum within inlier_px
    of radius r of at least support_edge_min and support_ratio times the ray's median step from
    2 inlier_px to support_flank_px off r: noise and texture make steps all along a ray, a rim
    one at the circle. Or, inside and outside judged apart (the flank's two sides: from 2
    inlier_px to support_flank_px inside r and outside it), at least support_ratio times the
    median step of the quieter side and at least every step of the busier one (the side of the
    higher median; outside on ties): a busy backdrop (fine stripes, a checkerboard) makes steps
    as large as the rim's all along the outer side, so that the whole flank's median hides a
    rim that stands out of the sphere's side and is the largest step of the backdrop's; a noise
    or clutter step next to a rim within support_flank_px is not the largest there. Rays leaving
    the frame count as without: a circle mostly outside the frame is not the sphere."""
    return int(_support_rays(img, dirs, cx, cy, r, p).sum()) / len(dirs)


def _tangent_tries(img, dirs, cx, cy, r, p):
    """The circles tried from one tangent circle (cx, cy, r) of _tangent: where fine_passes - 1
    passes from it lead (None when a fit fails), then the tangent circle itself. Where the limb
    is dark against a dark backdrop over a wide arc (a third of the rim), the rim's steps there
    are weak (7-21 against texture bands' 20-50 a few pixels inside), and the passes from a
    tangent circle lying on the rim slide back to the bands: the circle itself is the better
    supported (rig-unseen frame 25 of seed 401: the passes' circles 0.45 and below, the fit
    0.453 at 3.3 px off centre, the tangent circle 0.500 at 0.4 px; _outermost and _rim take it
    from there to 0.23 px)."""
    return _passes(img, dirs, cx, cy, r, p), (cx, cy, r)


def _tangent(img, dirs, fit, p):
    """The sphere's weakly supported fit tried again from larger circles internally tangent to it
    where its support lies: where the limb darkens to the backdrop's level on one side, the fine
    passes can settle on a circle through that arc's inner steps (the limb's shading or a texture
    band 1-4 px inside the rim) and through the rim on the lit side, a circle 1-4 px off
    towards the lit side (support 0.45-0.62) that _grow's larger circles from the same centre do
    not leave. Here the supported rays' directions, summed in ray order, point to the lit arc;
    from the circle with the radius fine_window_px and 2 fine_window_px larger and the centre as
    far the other way (tangent to the fit there), fine_passes - 1 passes each (as _grow's), and
    that circle itself (_tangent_tries), then their support; the best supported of the fit and
    these four (the fit on ties, then the first) replaces it;
    again from the new circle while one of them replaced it and its support is below
    (1 + min_support) / 2, at most GROW_ROUNDS tries. For the sphere, after every decision (which
    circle is the sphere, cut, two spheres), where it moves the sphere's circle, never whether the
    frame is answered; and in _rescue, on a refused frame's best fit, where it decides that (and
    in the second search of a frame with a camera file, whose sphere after these tries must be a
    lit one: _find_sphere_v2).
    Returns (cx, cy, r, support)."""
    decisive = _decisive_support(p)
    best = fit
    if not best[3] < decisive:
        return best
    # the supported rays: of the fit (its support again, the same value), then of the circle
    # that replaced it
    sup = _support_rays(img, dirs, best[0], best[1], best[2], p)
    for _ in range(GROW_ROUNDS):
        if best[3] >= decisive:
            break
        mx, my = _seqsum(dirs[sup, 0].tolist()), _seqsum(dirs[sup, 1].tolist())
        nm = math.sqrt(mx * mx + my * my)
        if not nm > 0.0:
            break
        ux, uy = mx / nm, my / nm
        cur, cur_sup = best, sup
        for k in (1, 2):
            d = k * p["fine_window_px"]
            for c in _tangent_tries(img, dirs, best[0] - d * ux, best[1] - d * uy, best[2] + d, p):
                if c is None:
                    continue
                cx, cy, r = c
                t = _support_rays(img, dirs, cx, cy, r, p)
                s = int(t.sum()) / len(dirs)
                if s > cur[3]:
                    cur, cur_sup = (cx, cy, r, s), t
        if cur is best:
            break
        best, sup = cur, cur_sup
    return best


def _refit_rays(img, dirs, c, p):
    """The rays the refits (_outermost, _rim) read for circle c: its support's rays (_ray_scores
    from its centre, +-support_flank_px) and their edge candidates (_peaks at ray_edge_min)."""
    rays = _ray_scores(img, dirs, c[0], c[1], c[2], p["support_flank_px"])
    return rays, _peaks(rays[0], rays[1], p["ray_edge_min"])


def _wide(img, dirs, fit, rays, peaks, p):
    """A refused frame's best fit (_rescue), when supported below WIDE_BELOW, refitted through the
    outermost edges from 1.5 inlier_px inside it to WIDE_OUT inlier_px outside (_outermost's fit;
    rays, peaks: its support's rays and their edge candidates); that circle with its support when
    better supported than the fit, else the fit itself. The sphere's is judged by its rims
    instead (_final_circle)."""
    if not fit[3] < WIDE_BELOW:
        return fit
    cx, cy, r = _outermost(rays, peaks, dirs, fit, p, WIDE_OUT)
    s = _support(img, dirs, cx, cy, r, p)
    return (cx, cy, r, s) if s > fit[3] else fit


def _limb_shading(img, dirs, cx, cy, r, p):
    """How much brighter a circle's inside is than its edge: over the rays from (cx, cy) whose
    samples all lie in the frame, the median of each ray's brightest sample (largest channel,
    bilinear) from r/4 to 3r/4 (every pixel: r/4 + i) over the median of its brightest from
    support_flank_px to 2 inlier_px inside the circle (the support's inner flank, every half
    pixel), the latter at least 1. None with fewer than 8 such rays (too little of the circle
    in the frame to tell)."""
    inner = [r * 0.25 + i for i in range(int(math.floor(r * 0.5)) + 1)]
    edge = [r - 0.5 * i for i in range(int(math.ceil(4.0 * p["inlier_px"])),
                                       int(math.floor(2.0 * p["support_flank_px"])) + 1)]
    if not edge:
        return None
    rho = np.array(inner + edge, np.float64)
    v = _sample(img, cx + rho[None, :] * dirs[:, 0:1], cy + rho[None, :] * dirs[:, 1:2]).max(axis=2)
    ok = ~np.isnan(v).any(axis=1)
    if int(ok.sum()) < 8:
        return None
    v = v[ok]
    ni = len(inner)
    return _median(v[:, :ni].max(axis=1).tolist()) / max(1.0, _median(v[:, ni:].max(axis=1).tolist()))


def _shadings(img, dirs, a, b, p):
    """Sphere a's and circle b's shading (_limb_shading), to compare b's with a's: None when a's is
    unknown or below LIMB_MIN (a sphere over-exposed to its rim shows none, and then nothing is
    told apart) or b's is unknown."""
    sa = _limb_shading(img, dirs, a[0], a[1], a[2], p)
    if sa is None or not sa >= LIMB_MIN:
        return None
    sb = _limb_shading(img, dirs, b[0], b[1], b[2], p)
    return None if sb is None else (sa, sb)


def _flat(img, dirs, a, b, p):
    """Whether circle b's inside is flat where sphere a's darkens towards its rim (see LIMB_SHARE):
    then b is no second sphere."""
    s = _shadings(img, dirs, a, b, p)
    return s is not None and s[1] - 1.0 < LIMB_SHARE * (s[0] - 1.0)


def _in_frame(dirs, cx, cy, r, p, h, w):
    """How many rays from (cx, cy) keep the support's samples (_ray_scores within
    support_flank_px of r) in the frame: both ends of that segment of the ray inside
    [0, w - 1) x [0, h - 1) (convex, so every sample between is too; crop2.cpp tests the same)."""
    m = int(math.floor(p["support_flank_px"] * 2.0))
    ends = np.array([-1.0 - m, 2 * m + 1 - m], np.float64)
    rho = r + ends * 0.5
    X = cx + rho[None, :] * dirs[:, 0:1]
    Y = cy + rho[None, :] * dirs[:, 1:2]
    ok = (X >= 0.0) & (Y >= 0.0) & (X < w - 1) & (Y < h - 1)
    return int(ok.all(axis=1).sum())


def _in_frame_support(dirs, c, p, h, w, share, support=None):
    """Circle c's support (or `support`, a share of all its rays: its beside support) over its
    rays in the frame (its supported rays are among them), when at least `share` of its rays are
    in the frame; else None."""
    n = _in_frame(dirs, c[0], c[1], c[2], p, h, w)
    if n == 0 or n < share * len(dirs):
        return None
    return (c[3] if support is None else support) * len(dirs) / n


def _beside_support(img, dirs, a, b, p):
    """Circle b's support with its rays whose point on b lies on sphere a's disc counted as
    without: there a's texture or rim is no rim of b's (a sphere behind a is hidden there, as the
    post hides the sphere's own rim). b's support itself when the circles do not overlap."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    if dx * dx + dy * dy >= (a[2] + b[2]) * (a[2] + b[2]):
        return b[3]
    X = b[0] + b[2] * dirs[:, 0]
    Y = b[1] + b[2] * dirs[:, 1]
    off = (X - a[0]) * (X - a[0]) + (Y - a[1]) * (Y - a[1]) >= a[2] * a[2]
    return int((_support_rays(img, dirs, b[0], b[1], b[2], p) & off).sum()) / len(dirs)


def _lit(img, dirs, c, p):
    """Whether circle c may be a lit sphere cut by the frame edge: its inside, over its rays in the
    frame, no darker than its edge (_limb_shading at least CUT_SHADE), or too little of it in the
    frame to tell."""
    s = _limb_shading(img, dirs, c[0], c[1], c[2], p)
    return s is None or s >= CUT_SHADE


def _textured(img, dirs, c, p):
    """Whether circle c may be a sphere by its inside: its texture steps (_texture_steps) at least
    CUT_TEXTURE, or too few of its rays in the frame to tell."""
    t = _texture_steps(img, dirs, c, p)
    return t is None or t >= CUT_TEXTURE


def _cut_message(cut, p):
    return (f"sphere cut by the frame edge ({100 * cut:.0f} % of its rim outside the frame, "
            f"at most {100 * p['max_cut']:.0f} %)")


def _sized(r, rmin, rmax):
    """Whether radius r may be the sphere's: within [0.9 rmin, 1.1 rmax] (radius_range's range,
    10 % wider each way)."""
    return rmin * 0.9 <= r <= rmax * 1.1


def _no_sphere_message(img, dirs, fits, p, rmin, rmax):
    """The error when no circle is the sphere: the cut sphere's, of the best supported fit (first
    on ties) of a radius in range with more than max_cut of its rim outside the frame, at least
    half its rays in the frame, min_support of them supporting it, its inside no darker than its
    edge (_limb_shading known and at least CUT_SHADE) and textured (_textured); without one, no
    sphere found."""
    h, w = img.shape[:2]
    for i in sorted(range(len(fits)), key=lambda i: (-fits[i][3], i)):
        c = fits[i]
        if not _sized(c[2], rmin, rmax):
            continue
        cut = rim_outside(c[0], c[1], c[2], h, w)
        if not cut > p["max_cut"]:
            continue
        s = _in_frame_support(dirs, c, p, h, w, 0.5)
        if s is None or not s >= p["min_support"]:
            continue
        sh = _limb_shading(img, dirs, c[0], c[1], c[2], p)
        if sh is not None and sh >= CUT_SHADE and _textured(img, dirs, c, p):
            return _cut_message(cut, p)
    return NO_SPHERE


def _two_spheres(a, b):
    return (f"two spheres in frame (circles at ({a[0] + 0.5:.1f}, {a[1] + 0.5:.1f}) r {a[2]:.1f} "
            f"and ({b[0] + 0.5:.1f}, {b[1] + 0.5:.1f}) r {b[2]:.1f})")


def _apart(a, b, p):
    """Whether circles a and b may be two spheres by their geometry: neither centre inside the
    other circle (else the sphere's own texture or limb), radii within a factor 1 + 2 r_tol."""
    rr = max(a[2], b[2])
    if (a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) < rr * rr:
        return False
    return max(a[2], b[2]) <= (1.0 + 2.0 * p["r_tol"]) * min(a[2], b[2])


def _colours(img, dirs, c):
    """The shares of circle c's samples on COLOUR_RINGS rings in the 14 colour bins (hues 0-11,
    dark, light); None with fewer than COLOUR_IN_FRAME of them in the frame."""
    rho = np.array([c[2] * COLOUR_REACH * math.sqrt((i + 0.5) / COLOUR_RINGS)
                    for i in range(COLOUR_RINGS)], np.float64)
    v = _sample(img, c[0] + rho[None, :] * dirs[:, 0:1], c[1] + rho[None, :] * dirs[:, 1:2])
    v = v.reshape(-1, 3)
    v = v[~np.isnan(v).any(axis=1)]
    n = len(v)
    if n < COLOUR_IN_FRAME * (len(dirs) * COLOUR_RINGS):
        return None
    b, g, r = v[:, 0], v[:, 1], v[:, 2]
    mx, mn = v.max(axis=1), v.min(axis=1)
    vref = np.sort(mx)[int(math.floor(COLOUR_QUANTILE * (n - 1)))]
    col = (mx - mn) > COLOUR_SAT * mx
    d = np.where(col, mx - mn, 1.0)
    h = np.where(mx == r, (g - b) / d, np.where(mx == g, 2.0 + (b - r) / d, 4.0 + (r - g) / d)) * 60.0
    h = np.where(h < 0.0, h + 360.0, h)
    counts = np.bincount(np.minimum(np.floor(h[col] / 30.0), 11.0).astype(np.int64), minlength=12)
    dark = ~col & (mx < COLOUR_DARK * vref)
    counts = counts.tolist() + [int(dark.sum()), int((~col & ~dark).sum())]
    return [k / n for k in counts]


def _alike(img, dirs, a, b):
    """Whether circle b's colours are sphere a's (_colours within COLOUR_TOL), or either circle has
    too few samples in the frame to tell."""
    ca, cb = _colours(img, dirs, a), _colours(img, dirs, b)
    return ca is None or cb is None or _seqsum([abs(x - y) for x, y in zip(ca, cb)]) <= COLOUR_TOL


def _second(img, dirs, a, b, p):
    """Whether circle b is a second sphere beside sphere a: apart (_apart), b's inside not flat
    where a's is shaded (_flat), its colours a's (_alike)."""
    return _apart(a, b, p) and not _flat(img, dirs, a, b, p) and _alike(img, dirs, a, b)


def _second_beside(img, dirs, a, b, p):
    """_second, and b's beside support at least min_support (computed last, only then: it is costly)."""
    return _second(img, dirs, a, b, p) and _beside_support(img, dirs, a, b, p) >= p["min_support"]


def _texture_steps(img, dirs, c, p):
    """The median, over circle c's rays whose samples all lie in the frame, of the number of colour
    steps (_ray_edges' candidates) from 0.2 r to 0.8 r from its centre: the printed texture's
    bands; None with fewer than 8 such rays."""
    edges = _ray_edges(img, dirs, c[0], c[1], 0.5 * c[2], 0.3 * c[2], p)
    n = [float(len(e)) for e in edges if e is not None]
    return _median(n) if len(n) >= 8 else None


def _weak_second(img, dirs, a, b, p):
    """Whether circle b, below min_support, is a second sphere beside sphere a by its likeness to
    it (see SECOND_WEAK): apart, lit as a is (shading above 1 at least WEAK_SHARE of a's, a's at
    least LIMB_MIN), its texture within TEXTURE_TOL of a's, its colours a's (_alike), and its
    beside support at least SECOND_WEAK (computed last: it is costly)."""
    if not _apart(a, b, p):
        return False
    s = _shadings(img, dirs, a, b, p)
    if s is None or not s[1] - 1.0 >= WEAK_SHARE * (s[0] - 1.0):
        return False
    ta, tb = _texture_steps(img, dirs, a, p), _texture_steps(img, dirs, b, p)
    if ta is None or tb is None or not abs(ta - tb) <= TEXTURE_TOL or not _alike(img, dirs, a, b):
        return False
    return _beside_support(img, dirs, a, b, p) >= SECOND_WEAK


def _cut_peak_fits(img, dirs, weak, s, a, p):
    """The fits (_fine; s: the coarse scale) of the weaker coarse peaks (WEAK_PEAK) whose circle
    is cut by the frame edge and whose centre lies outside sphere a's circle."""
    h, w = img.shape[:2]
    out = []
    for c in weak:
        if (rim_outside(c[0], c[1], c[2], h, w) > 0
                and (c[0] - a[0]) * (c[0] - a[0]) + (c[1] - a[1]) * (c[1] - a[1]) >= a[2] * a[2]):
            f = _fine(img, dirs, c, s, p)
            if f is not None:
                out.append(f)
    return out


def rim_outside(cx, cy, r, h, w, k=256):
    """Fraction of the circle's rim outside the frame [0, w - 1] x [0, h - 1] (k points)."""
    d = _ray_dirs(k)
    X = cx + r * d[:, 0]
    Y = cy + r * d[:, 1]
    out = (X < 0) | (X > w - 1) | (Y < 0) | (Y > h - 1)
    return int(out.sum()) / k


def _check_size(frame, camera):
    cw, ch = int(_cam_get(camera, "width", 640)), int(_cam_get(camera, "height", 512))
    h, w = frame.shape[:2]
    if (w, h) != (cw, ch):
        raise ValueError(f"frame is {w}x{h}, the camera file's calibration is for {cw}x{ch}")


def _find_sphere_v2(frame, p, camera=None, fits_out=None, cov_out=None):
    h, w = frame.shape[:2]
    if camera is not None:
        _check_size(frame, camera)
    rmin, rmax = radius_range(h, w, p, camera)
    try:
        return _search(frame, p, rmin, rmax, rmin, fits_out, cov_out)
    except NoSphere as e:
        # No sphere found within a camera file's radius range: searched again with the coarse
        # peaks as close together as the wide search's. A peak clears the centres near it (cand_gap
        # times the smallest radius) so that one circle does not take every candidate place; a
        # camera file's smallest radius makes that neighbourhood about four times wider, and where
        # the limb is shaded dark against a dark backdrop the one peak left on the sphere can lie
        # 4-18 px off with a radius 6-19 px small (docs/bench/localise.md). From there the fine
        # passes settle on the shading's edge inside the rim, though the rim itself is supported
        # above min_support.
        # Like the refused frame's other tries, the sphere found so is kept only as a lit sphere
        # (_lit_sphere): a clutter circle a denser search finds in a frame without a sphere is
        # mostly shaded flat. Measured (docs/bench/localise.md) on seeds 475-478 and 483-522: 5 of
        # the 8 clear spheres refused are answered (poses within 0.19 deg, the printed circles
        # within 0.5 px and 0.5 %); none of the 4 400 frames to refuse is answered (without the
        # shading test one `none` frame was); a lit clutter disk of spent seed 413 is, and the
        # refinement flags it. The other errors are about a sphere found, and are not searched
        # again; when the second search finds none either, the error is the first's.
        wide = radius_range(h, w, p)[0]
        if not (str(e) == NO_SPHERE and wide < rmin):
            raise
        try:
            return _search(frame, p, rmin, rmax, wide, None, cov_out, lit_only=True)
        except NoSphere:
            raise e from None


def _search(frame, p, rmin, rmax, gap_r, fits_out, cov_out, lit_only=False):
    """The sphere's circle within radius range [rmin, rmax] (_find_sphere_v2), the coarse peaks
    gap_r apart (_coarse); lit_only: the sphere only as a lit sphere (_lit_sphere), else
    NoSphere."""
    h, w = frame.shape[:2]
    cands, weak_peaks, s = _coarse(frame, p, rmin, rmax, gap_r)
    decisive = _decisive_support(p)
    dirs = _ray_dirs(p["rays"])
    fits = []
    for c in cands:
        # a peak whose centre lies inside a decisively supported fit is that circle again or
        # the texture's arcs inside it: neither a better sphere nor a second one (the check below
        # passes over circles whose centre lies inside the other), so it is not refined
        if any(f[3] >= decisive and (c[0] - f[0]) * (c[0] - f[0]) + (c[1] - f[1]) * (c[1] - f[1]) < f[2] * f[2]
               for f in fits):
            continue
        f = _fine(frame, dirs, c, s, p)
        if f is not None:
            fits.append(f)
    if fits:
        # the best supported fit (first on ties), when weakly supported, tried from larger circles
        # (and from smaller ones too when below min_support)
        ib = min(range(len(fits)), key=lambda i: (-fits[i][3], i))
        # again from the circle it moved to, while that is better supported and still weak, at
        # most GROW_ROUNDS tries. A fit below min_support (no sphere: the frame would be
        # refused) is tried from smaller circles too, in every try; a sphere's weak fit is not:
        # a smaller circle a few rays better supported is as often a texture band inside a dark
        # limb as the rim (tried on every weak fit, a `shifts` frame's fit 0.18 px off the rim moved
        # 1.2 px off)
        fits[ib] = _grown(frame, dirs, fits[ib], p, fits[ib][3] < p["min_support"], decisive)
        # and the first fit too (_grow_first)
        _grow_first(frame, dirs, fits, ib, p)
        # a best fit still below min_support (the frame would be refused) tried from tangent
        # circles too, and through a wider band, kept only as a lit sphere (_rescue)
        fits[ib] = _rescue(frame, dirs, fits[ib], p)
        # and when it is still below, every other fit tried the same way (_retry_rest)
        _retry_rest(frame, dirs, fits, ib, p, rmin, rmax)
    if fits_out is not None:
        fits_out.extend(fits)
    found = [f for f in fits if f[3] >= p["min_support"] and _sized(f[2], rmin, rmax)]
    if not found:
        raise NoSphere(_no_sphere_message(frame, dirs, fits, p, rmin, rmax))
    # the best supported circle is the sphere; another well supported one of about its size,
    # neither centre inside the other circle, is a second sphere, and which one to measure is
    # not ours to guess
    order = sorted(range(len(found)), key=lambda i: (-found[i][3], i))
    a = found[order[0]]
    cut = rim_outside(a[0], a[1], a[2], h, w)
    if cut > p["max_cut"]:
        # a circle darker inside than at its edge, or smooth inside (a disk of the clutter), is no
        # cut sphere: the frame is then told as one without a sphere is (a lit, textured cut sphere
        # below it, or none)
        raise NoSphere(_cut_message(cut, p) if _lit(frame, dirs, a, p) and _textured(frame, dirs, a, p)
                       else _no_sphere_message(frame, dirs, fits, p, rmin, rmax))
    # the weaker coarse peaks' circles cut by the frame edge judged with the fits (WEAK_PEAK)
    cut_fits = _cut_peak_fits(frame, dirs, weak_peaks, s, a, p)
    found += [f for f in cut_fits if f[3] >= p["min_support"] and _sized(f[2], rmin, rmax)]
    fits += cut_fits
    for b in found:
        if b is not a and _second_beside(frame, dirs, a, b, p):
            raise NoSphere(_two_spheres(a, b))
    # a second sphere partly outside the frame: judged by its rays in the frame (SECOND_IN_FRAME)
    for b in fits:
        if b[3] >= p["min_support"] or not _sized(b[2], rmin, rmax):
            continue  # judged above, or not of a sphere's size
        s_in = _in_frame_support(dirs, b, p, h, w, SECOND_IN_FRAME)
        # its beside support last: its own support unless the circles overlap, and then a
        # support's rays again
        if (s_in is not None and s_in >= p["min_support"] and _second(frame, dirs, a, b, p)
                and _in_frame_support(dirs, b, p, h, w, SECOND_IN_FRAME,
                                      _beside_support(frame, dirs, a, b, p)) >= p["min_support"]):
            raise NoSphere(_two_spheres(a, b))
    # a second sphere whose fit settled on its texture: weak circles of the sphere's size beside
    # it tried again as the sphere's weak fit is (SECOND_RETRY), until min_support; one above
    # that but below decisive, not a second sphere as it is (above), until decisive
    for b in fits:
        if (b is a or not SECOND_RETRY <= b[3] < decisive or not _sized(b[2], rmin, rmax)
                or not _apart(a, b, p)):
            continue
        weak = b[3] < p["min_support"]
        g = _grown(frame, dirs, b, p, True, p["min_support"] if weak else decisive)
        if ((weak or g is not b) and g[3] >= p["min_support"] and _sized(g[2], rmin, rmax)
                and _second_beside(frame, dirs, a, g, p)):
            raise NoSphere(_two_spheres(a, g))
        # still weak: a second sphere when it looks like the sphere (SECOND_WEAK)
        if (SECOND_WEAK <= g[3] < p["min_support"] and _sized(g[2], rmin, rmax)
                and _weak_second(frame, dirs, a, g, p)):
            raise NoSphere(_two_spheres(a, g))
    # a weakly supported sphere tried from larger circles tangent to it on its supported arc
    a = _tangent(frame, dirs, a, p)
    if lit_only and not _lit_sphere(frame, dirs, a, p):
        raise NoSphere(NO_SPHERE)
    return _final_circle(frame, dirs, a, p, cov_out)


def _last_step(rays, peaks, dirs, c, p):
    """The last step from circle c: refitted through the outermost edges near it (_outermost),
    then moved to the rims and refitted through them (_rim); rays, peaks: c's support's rays and
    their edge candidates (_refit_rays; the C++ keeps them from computing the support). Returns
    ((cx, cy, r), near) as _rim."""
    return _rim(rays, peaks, dirs, c, _outermost(rays, peaks, dirs, c, p), p)


def _final_circle(img, dirs, a, p, cov=None):
    """The sphere's circle: the last step from its fit a (_last_step) and, when a is supported
    below WIDE_BELOW, from a refitted through the outermost edges of the wider band (WIDE_OUT,
    about a's support's rays); the wider band's circle when more of its rims lie near it (see
    RIM_NEAR), else the fit's. The wider band's circle is not tried when it is a itself (the
    refit failed). Returns (cx, cy, r). A list `cov` gets that circle's centre's covariance from
    its rims on the fit's rays, when there is one (_rim; the refinement weighs it against the
    refined centre: training/refine.py CENTRE_FUSE_PX)."""
    rays, peaks = _refit_rays(img, dirs, a, p)
    c, near = _last_step(rays, peaks, dirs, a, p)
    if a[3] < WIDE_BELOW:
        w = _outermost(rays, peaks, dirs, a, p, WIDE_OUT)
        if w != (a[0], a[1], a[2]):
            cw, near_w = _last_step(*_refit_rays(img, dirs, w, p), dirs, w, p)
            if near_w > near:
                c = cw
    if cov is not None:
        _rim(rays, peaks, dirs, a, c, p, cov)
    return c


# ---- the public steps -----------------------------------------------------------------------

def find_sphere(frame, p=None, camera=None, fits=None, cov=None):
    """(cx, cy, r, bg) of the sphere in a BGR uint8 frame (OpenCV pixel coordinates: pixel
    centres at integers); bg is v1's background colour, v2's fill colour. NoSphere says why
    there is none. v2 expects an undistorted frame (see undistort, crop_frame). A list `fits`
    (v2) gets the circles the sphere was chosen from (the first search's, _find_sphere_v2),
    (cx, cy, r, support) each, also when there
    is none: what scripts/sphere_check.py shows a user of a refused frame. A list `cov` (v2)
    gets the covariance of the circle's centre from its rims, (cxx, cxy, cyy) in px^2
    (_centre_covariance), when there is one."""
    p = p or DEFAULTS
    frame = _as_bgr(frame)
    if p["name"] == NAME_V1:
        return _find_sphere_v1(frame, p)
    cx, cy, r = _find_sphere_v2(frame, p, camera, fits, cov)
    return cx, cy, r, np.asarray(p["fill"], np.float64)


def rim_support(frame, circle, p=None):
    """Which rays from the circle's centre find its rim, as the support counts them (_support): a
    bool per ray, ray k pointing at the angle 2 pi k / rays (x right, y down). frame: undistorted
    BGR uint8; circle: (cx, cy, r, ...), OpenCV pixel coordinates."""
    p = p or DEFAULTS
    cx, cy, r = (float(v) for v in circle[:3])
    return _support_rays(_as_bgr(frame), _ray_dirs(p["rays"]), cx, cy, r, p)


def rim_from(frame, circle, p=None, cov=None):
    """The sphere's rim found from a circle measured another way (v2 only): the refinement's,
    whose radius the texture fixes within about 0.1 % (docs/refine.md, "The circle after
    refinement"). The rim step alone (_rim, from the circle's support rays): on each ray the
    step peak nearest the circle, its outer half-maximum less the edge half-width, the circle
    refitted through those rims. Unlike the localisation's last step it takes no outermost
    edge: from so near a start the nearest peak is the rim's, where the outermost can be a
    backdrop's edge just outside it. frame: undistorted BGR uint8; circle: (cx, cy, r), OpenCV
    pixel coordinates. Returns (cx, cy, r), or None with fewer than 8 rims or none of them near
    the refitted circle (_rim's near, 0). A list `cov` gets its centre's covariance from those
    rims, (cxx, cxy, cyy) in px^2 (_centre_covariance), when there is one."""
    p = p or DEFAULTS
    img = _as_bgr(frame)
    dirs = _ray_dirs(p["rays"])
    c = tuple(float(v) for v in circle)
    rays, peaks = _refit_rays(img, dirs, c, p)
    v = []
    out, near = _rim(rays, peaks, dirs, c, c, p, v)
    if not near > 0:
        return None
    if cov is not None:
        cov.extend(v)
    return out


def crop(frame, cx, cy, r, bg, p=None):
    """Square crop around the circle, outside the frame filled with bg, resized to size x size;
    v2 also fills everything farther than r (1 + mask_frac) from the centre."""
    p = p or DEFAULTS
    frame = _as_bgr(frame)
    h, w = frame.shape[:2]
    half = r * p["margin"]
    x0 = math.floor(cx - half + 0.5)
    y0 = math.floor(cy - half + 0.5)
    side = max(1, math.floor(2 * half + 0.5))
    pad_l, pad_t = max(0, -x0), max(0, -y0)
    pad_r, pad_b = max(0, x0 + side - w), max(0, y0 + side - h)
    fill = [int(np.clip(math.floor(v + 0.5), 0, 255)) for v in bg]
    padded = cv2.copyMakeBorder(frame, pad_t, pad_b, pad_l, pad_r, cv2.BORDER_CONSTANT, value=fill)
    roi = padded[y0 + pad_t:y0 + pad_t + side, x0 + pad_l:x0 + pad_l + side]
    out = cv2.resize(roi, (p["size"], p["size"]), interpolation=cv2.INTER_AREA)
    if p["name"] == NAME_V2:
        out[_outside_mask(cx, cy, r, x0, y0, side, p)] = fill
    return out


def _outside_mask(cx, cy, r, x0, y0, side, p):
    """Output pixels whose centre, mapped back into the frame, lies farther than
    r (1 + mask_frac) from the circle's centre."""
    S = p["size"]
    scale = side / S
    u = (np.arange(S, dtype=np.float64) + 0.5) * scale - 0.5
    dx = (x0 + u) - cx
    dy = (y0 + u) - cy
    rm = r * (1.0 + p["mask_frac"])
    return (dy * dy)[:, None] + (dx * dx)[None, :] > rm * rm


def crop_frame(frame, p=None, camera=None):
    """Steps up to the crop: (BGR uint8 size x size crop, (cx, cy, r)) of a frame; with a camera,
    undistorted first (v2)."""
    p = p or DEFAULTS
    frame = _as_bgr(frame)
    if camera is not None and p["name"] == NAME_V2:
        frame = undistort(frame, camera)
    cx, cy, r, bg = find_sphere(frame, p, camera)
    return crop(frame, cx, cy, r, bg, p), (cx, cy, r)


def normalise(crop_bgr, p=None):
    """BGR uint8 crop -> float32 CHW tensor, RGB, (v/255 - mean) / std (step 8)."""
    p = p or DEFAULTS
    rgb = cv2.cvtColor(crop_bgr, cv2.COLOR_BGR2RGB).astype(np.float32) / 255.0
    rgb = (rgb - np.asarray(p["mean"], np.float32)) / np.asarray(p["std"], np.float32)
    return np.ascontiguousarray(rgb.transpose(2, 0, 1))


def preprocess(frame, p=None, camera=None):
    """Full frame (BGR uint8) -> float32 [3, size, size] network input."""
    p = p or DEFAULTS
    return normalise(crop_frame(frame, p, camera)[0], p)


def preprocess_file(path, p=None, camera=None):
    """Read an image file and preprocess it; errors name the file."""
    frame = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if frame is None:
        raise ValueError(f"{path}: cannot decode image (missing, corrupt or not an image)")
    if frame.dtype != np.uint8:
        raise ValueError(f"{path}: expected 8-bit pixels, got {frame.dtype}")
    try:
        return preprocess(frame, p, camera)
    except NoSphere as e:
        raise NoSphere(f"{path}: {e}") from None
