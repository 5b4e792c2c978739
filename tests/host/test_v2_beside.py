"""sphere-crop-v2 counts a circle's rays that fall on the sphere's own disc as without support when
it judges the circle as a second sphere: there the sphere's texture or rim is no rim of the other
circle's, and a sphere behind it would be hidden there, as the post hides the sphere's own rim
(training/preprocess.py _beside_support, docs/interfaces.md step 5). Two frames of the independent
ray-caster (bench/raycast) were refused as "two spheres" by a circle overlapping the sphere:
frame 14 of the `rig` family, seed 410 (a clutter ellipse of the sphere's size cut by the frame's
bottom edge: its rays in the frame 0.44 supported, 10 of its 44 supported rays on the sphere), and
frame 82 of the `rig-photo` family, seed 503 (a motorcycle photo: a circle grown to 0.422, 10 of
its 54 supported rays on the sphere). Both are now answered within 0.5 px and 0.5 % of the truth.
The C runtime gives the same circles."""
import cv2
import numpy as np
import pytest

from training import preprocess as pp
from v2_raycast_cases import CAMERA, assert_same_circles_in_c, assert_within_limits, params, render_seeded

OVERLAPPING = [(("rig", 14, "23.404_-18.313_11.347.png"), 410),
               (("rig-photo", 82, "-4.913_15.483_18.591.png"), 503)]


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    return render_seeded(tmp_path_factory.mktemp("beside"), OVERLAPPING)


def test_answered_within_limits(frames, monkeypatch):
    p = params()
    imgs = assert_within_limits(frames, p)
    # with the rays on the sphere's disc supporting the other circle: two spheres (what this guards)
    monkeypatch.setattr(pp, "_beside_support", lambda img, dirs, a, b, p: b[3])
    for img in imgs:
        with pytest.raises(pp.NoSphere, match="two spheres"):
            pp.find_sphere(img, p, CAMERA)


def test_rays_on_the_sphere_do_not_support():
    """A circle overlapping the sphere loses the support of its rays on the sphere's disc; one
    apart from it keeps its own."""
    p = params()
    dirs = pp._ray_dirs(p["rays"])
    img = np.full((512, 640, 3), 60, np.uint8)
    cv2.circle(img, (200, 256), 100, (230, 230, 230), -1, cv2.LINE_AA)  # the sphere
    cv2.circle(img, (380, 256), 100, (160, 160, 160), -1, cv2.LINE_AA)  # a disc over its edge
    a = (200.0, 256.0, 100.0, 1.0)
    whole = pp._support(img, dirs, 380.0, 256.0, 100.0, p)
    assert whole == 1.0  # the disc's rim is clear all round, on the sphere too
    beside = pp._beside_support(img, dirs, a, (380.0, 256.0, 100.0, whole), p)
    assert beside == (128 - 19) / 128  # 19 of its rays (+-26 deg about the centres' line) on the sphere
    assert pp._beside_support(img, dirs, a, (420.0, 256.0, 100.0, 0.5), p) == 0.5  # apart


def test_same_circles_in_c(frames, tmp_path, poseinfer, timeout_scale):
    assert_same_circles_in_c(poseinfer, [path for path, _ in frames], tmp_path, timeout_scale)
