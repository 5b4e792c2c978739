"""sphere-crop-v2: frames of the independent ray-caster (bench/raycast) that hold one whole sphere
and were not answered (docs/bench/localise.md, "unanswered frames"), and frames with two spheres
that must stay refused.

- `rig` seed 111 frame 32 and `rig-unseen` seed 113 frame 42 were refused as "two spheres in
  frame": beside the sphere, a bright disk of the clutter (r 102 against the sphere's 131) and a
  circle on a fine checkerboard backdrop, supported at 0.51 and 0.48 (real second spheres:
  0.44-0.91). Their insides are as bright at their edge as in their middle, where the sphere's
  darkens towards its rim (_limb_shading, _flat): now answered, within 0.5 px and 0.5 %.
- `edge` seed 135 frame 53 was refused as "no sphere found in frame": the fine stage settled
  2.9 px too large and 3 px off (support 0.34), on the backdrop's noise outside the rim, and the
  weak fit's retries tried only larger circles. A fit below min_support is now tried from smaller
  circles too (_grow, inward): it reaches the rim (support 0.84).
- `refuse` seed 0 frames 66 and 93 (two spheres: the second sphere with the least shading of
  that seed's, 0.62 of the first's, and the one supported at 0.44) are still refused.

The C runtime gives the same circles and the same errors as Python."""
import re

import cv2
import numpy as np
import pytest

from training import preprocess as pp
from v2_raycast_cases import (CAMERA, REPO, assert_same_circles_in_c, circle_error, params, poseinfer_lines,
                              render_frames, without_colours, without_wide_gap_retry)

FLAT_SECOND = [(111, ("rig", 32, "-21.721_26.051_-21.863.png")),
               (113, ("rig-unseen", 42, "-18.674_-17.016_18.017.png"))]
OUTSIDE_RIM = [(135, ("edge", 53, "0.906_-16.49_24.432.png"))]
TWO = [("refuse", 66, "15.12_-28.63_-0.939.png"), ("refuse", 93, "23.702_17.88_-23.983.png")]


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    folder = tmp_path_factory.mktemp("unanswered")
    out = {}
    for seed, case in FLAT_SECOND + OUTSIDE_RIM:
        sub = folder / f"s{seed}"
        sub.mkdir()
        out[case[0]] = render_frames(sub, [case], seed)[0]
    out["two"] = render_frames(folder, TWO)
    return out


def _found(path):
    return pp.find_sphere(cv2.imread(str(path), cv2.IMREAD_COLOR), params(), CAMERA)


def test_flat_second_circle_is_no_second_sphere(frames, monkeypatch):
    for family in ("rig", "rig-unseen"):
        path, truth = frames[family]
        ec, er = circle_error(_found(path), truth)
        assert ec <= 0.5 and er <= 0.5, (path.name, ec, er)
    # without the test of the second circle's inside both are refused (what this guards; without
    # the colours' test, which keeps them answered too)
    without_colours(monkeypatch)
    monkeypatch.setattr(pp, "_flat", lambda img, dirs, a, b, p: False)
    for family in ("rig", "rig-unseen"):
        with pytest.raises(pp.NoSphere, match="two spheres in frame"):
            _found(frames[family][0])


def test_second_sphere_still_refused(frames):
    for path, _ in frames["two"]:
        with pytest.raises(pp.NoSphere, match="two spheres in frame"):
            _found(path)


def test_weak_fit_outside_the_rim_moves_in(frames, monkeypatch):
    path, truth = frames["edge"]
    ec, er = circle_error(_found(path), truth)
    assert ec <= 0.5 and er <= 0.5, (path.name, ec, er)
    # with larger circles alone the fit stays outside the rim and the frame is refused
    grow = pp._grow
    monkeypatch.setattr(pp, "_grow", lambda img, dirs, fit, p, inward=False: grow(img, dirs, fit, p))
    without_wide_gap_retry(monkeypatch)
    with pytest.raises(pp.NoSphere, match="no sphere found in frame"):
        _found(path)


def test_same_circles_and_errors_in_c(frames, tmp_path, poseinfer, timeout_scale):
    answered = [frames[f][0] for f in ("rig", "rig-unseen", "edge")]
    assert_same_circles_in_c(poseinfer, answered, tmp_path, timeout_scale)
    paths = [path for path, _ in frames["two"]]
    for path, line in zip(paths, poseinfer_lines(poseinfer, paths, tmp_path, (), timeout_scale, rc=1)):
        with pytest.raises(pp.NoSphere) as e:
            _found(path)
        assert line["error"] == f"preprocess: {e.value}", line


def _disk(shaded, r=120.0, cx=320.0, cy=256.0):
    """A 640 x 512 frame, dark backdrop, one disk: flat, or brightest in the middle and darker
    towards its rim as a lit sphere."""
    yy, xx = np.mgrid[0:512, 0:640].astype(np.float64)
    d = np.hypot(xx - cx, yy - cy) / r
    inside = d < 1.0
    level = np.where(inside, 90.0 + (150.0 * np.sqrt(np.clip(1.0 - d * d, 0.0, 1.0)) if shaded else 130.0), 20.0)
    return np.repeat(np.round(level)[:, :, None], 3, axis=2).astype(np.uint8)


def test_limb_shading():
    p = params()
    dirs = pp._ray_dirs(p["rays"])
    flat = pp._limb_shading(_disk(False), dirs, 320.0, 256.0, 120.0, p)
    shaded = pp._limb_shading(_disk(True), dirs, 320.0, 256.0, 120.0, p)
    assert flat == 1.0
    assert shaded > 1.5 and shaded - 1.0 > (flat - 1.0) / pp.LIMB_SHARE
    # a circle almost wholly outside the frame: too few rays to tell
    assert pp._limb_shading(_disk(True), dirs, -110.0, 256.0, 120.0, p) is None
    a, b = (320.0, 256.0, 120.0, 1.0), (320.0, 256.0, 120.0, 1.0)
    assert pp._flat(_disk(True), dirs, a, b, p) is False  # the same shaded disk: a sphere
    assert pp._flat(_disk(False), dirs, a, b, p) is False  # the sphere itself flat: not told apart


def test_constants_the_same_in_c():
    # the tries' radii (larger, then smaller when inward) in host/libposeinfer/crop2.cpp
    # (LIMB_SHARE and LIMB_MIN: tests/host/test_v2_constants.py)
    src = (REPO / "host/libposeinfer/crop2.cpp").read_text()
    assert re.search(r"static const int steps\[4\] = \{1, 2, -1, -2\};\s*"
                     r"for \(int t = 0; t < \(inward \? 4 : 2\); t\+\+\)", src)
