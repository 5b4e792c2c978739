"""The renderer follows docs/conventions.md: marks at the (lat, lon) points of the test vectors land on their pixel_uv.

A test texture carries a small spherical cap of its own colour around each
point of tests/data/conventions_vectors.json; each case's pose is rendered
flat-shaded at the reference camera; every visible cap must appear within 1.5 px of the
point's pixel_uv, and no invisible one may appear at all.
"""
import json
import os

import cv2
import numpy as np
import pytest

from sim.camera import camera_from_dict
from sim.pose import body_direction, euler_to_matrix
from sim.render import Renderer

VECTORS_FILE = os.path.join(os.path.dirname(__file__), "..", "data", "conventions_vectors.json")

CAP_DEG = 2.0  # angular radius of each mark on the sphere
TOLERANCE_PX = 1.5
PALETTE = np.array([(255, 0, 0), (0, 255, 0), (0, 0, 255), (255, 255, 0), (255, 0, 255),
                    (0, 255, 255), (255, 255, 255), (255, 128, 0), (128, 0, 255)], float)


def load_vectors():
    with open(VECTORS_FILE, encoding="utf-8") as f:
        return json.load(f)


def mark_points(vectors):
    """The distinct (lat, lon) points of all cases, in first-seen order."""
    pts = []
    for case in vectors["cases"]:
        for p in case["points"]:
            key = (p["lat_deg"], p["lon_deg"])
            if key not in pts:
                pts.append(key)
    return pts


def mark_texture(points, h=1024):
    """Black equirectangular texture with a cap of PALETTE[k] around points[k] (caps are round on the sphere)."""
    w = 2 * h
    v, u = np.mgrid[0:h, 0:w] + 0.5
    lat = 90.0 - v / h * 180.0
    lon = u / w * 360.0 - 180.0
    d = body_direction(lat, lon)  # [3, h, w]
    tex = np.zeros((h, w, 3), np.uint8)
    for k, (la, lo) in enumerate(points):
        c = body_direction(la, lo)
        ang = np.degrees(np.arccos(np.clip(np.tensordot(c, d, axes=1), -1, 1)))
        tex[ang < CAP_DEG] = PALETTE[k].astype(np.uint8)
    return tex


def find_marks(img):
    """{palette index: (u, v) centroid, continuous pixel coordinates} of the coloured marks of a frame.

    A mark seen at a grazing angle is a sliver that may rasterise as a few
    separate blobs; blobs of one colour are pooled (they must lie close together).
    """
    f = img.astype(float)
    bright = f.sum(axis=2)
    n, labels = cv2.connectedComponents((bright > 60).astype(np.uint8), connectivity=8)
    pooled = {}
    for lab in range(1, n):
        rows, cols = np.nonzero(labels == lab)
        px = f[rows, cols]
        core = px[bright[rows, cols] >= np.percentile(bright[rows, cols], 75)].mean(axis=0)
        k = int(np.argmin(np.linalg.norm(PALETTE - core, axis=1)))
        wts = bright[rows, cols] / PALETTE[k].sum()
        pooled.setdefault(k, []).append((wts, cols + 0.5, rows + 0.5))
    found = {}
    for k, blobs in pooled.items():
        wts, us, vs = (np.concatenate(parts) for parts in zip(*blobs))
        assert np.ptp(us) < 40 and np.ptp(vs) < 40, f"mark {k} appears in several places"
        found[k] = (float(np.sum(wts * us) / wts.sum()), float(np.sum(wts * vs) / wts.sum()))
    return found


VECTORS = load_vectors()
POINTS = mark_points(VECTORS)


@pytest.fixture(scope="module")
def flat_renderer():
    camera = camera_from_dict(VECTORS["camera"], VECTORS_FILE)
    return Renderer(mark_texture(POINTS), camera, lights=(), lit=False, background=(0, 0, 0))


def test_marks_are_far_from_the_horizon():
    """Test validity: no cap straddles the visibility horizon, so 'visible' is the whole cap or none of it."""
    cam = VECTORS["camera"]
    r, d = cam["sphere_diameter_mm"] / 2, cam["distance_mm"]
    for case in VECTORS["cases"]:
        R = euler_to_matrix(*case["pose_deg"])
        for p in case["points"]:
            n = R @ body_direction(p["lat_deg"], p["lon_deg"])
            # visible <=> n . (C - r n) > 0 <=> n_z > r / D; margin as an angle on the sphere
            margin = np.degrees(np.arcsin(np.clip(n[2], -1, 1)) - np.arcsin(r / d))
            assert (margin > 0) == p["visible"], (case["pose_deg"], p)
            assert abs(margin) > CAP_DEG + 1.0, (case["pose_deg"], p, margin)


@pytest.mark.parametrize("case", VECTORS["cases"], ids=lambda c: "pose_" + "_".join(map(str, c["pose_deg"])))
def test_vectors(flat_renderer, case):
    img = flat_renderer.render(tuple(case["pose_deg"]))
    assert img.shape == (VECTORS["camera"]["height"], VECTORS["camera"]["width"], 3)
    found = find_marks(img)
    for p in case["points"]:
        k = POINTS.index((p["lat_deg"], p["lon_deg"]))
        label = f"pose {case['pose_deg']} point (lat {p['lat_deg']}, lon {p['lon_deg']})"
        if p["visible"]:
            assert k in found, f"{label}: visible in the vectors but not in the frame"
            du, dv = np.subtract(found[k], p["pixel_uv"])
            assert np.hypot(du, dv) <= TOLERANCE_PX, \
                f"{label}: found at {found[k]}, expected {p['pixel_uv']} (off by {np.hypot(du, dv):.2f} px)"
        else:
            assert k not in found, f"{label}: invisible in the vectors but appears at {found.get(k)}"


def test_pose_zero_sees_texture_centre_north_up(flat_renderer):
    """At pose (0, 0, 0) the image centre shows lon 0, lat 0; +lon is to the right, +lat up (not mirrored)."""
    found = find_marks(flat_renderer.render((0, 0, 0)))
    centre = found[POINTS.index((0, 0))]
    right = found[POINTS.index((0, 30))]
    up = found[POINTS.index((30, 0))]
    assert abs(centre[0] - 320) < 1 and abs(centre[1] - 256) < 1
    assert right[0] > centre[0] + 50 and up[1] < centre[1] - 50


OTHER_CAMERA = {"width": 400, "height": 300, "focal_mm": 8.0, "pixel_mm": 0.006,
                "distance_mm": 300.0, "sphere_diameter_mm": 50.0}  # sphere ~222 px across


@pytest.mark.parametrize("pose", [(0, 0, 0), (12, -27, 6), (-20, 15, 25)])
def test_other_camera_follows_the_same_model(pose):
    """A camera from a file (other size, aspect, focal length, distance, sphere): marks land where
    conventions.md's projection puts them, computed here from the pose and the camera."""
    cam = camera_from_dict(OTHER_CAMERA, "test camera")
    r = Renderer(mark_texture(POINTS), cam, lights=(), lit=False, background=(0, 0, 0))
    found = find_marks(r.render(pose))
    R = euler_to_matrix(*pose)
    for k, (lat, lon) in enumerate(POINTS):
        n = R @ body_direction(lat, lon)
        margin = np.degrees(np.arcsin(n[2]) - np.arcsin(cam.radius_mm / cam.distance_mm))
        if abs(margin) < CAP_DEG + 1.0:
            continue  # a cap on the horizon is partly visible; not a clean check
        if margin > 0:
            uv = cam.project(cam.radius_mm * n)[0]
            assert k in found, f"pose {pose} point {(lat, lon)}: visible but not found"
            assert np.hypot(*np.subtract(found[k], uv)) <= TOLERANCE_PX, (pose, (lat, lon), found[k], uv)
        else:
            assert k not in found, f"pose {pose} point {(lat, lon)}: invisible but found"
