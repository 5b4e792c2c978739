"""sphere-crop-v2 counts a circle's rays that fall on the sphere's own disc as without support when
it judges the circle as a second sphere: there the sphere's texture or rim is no rim of the other
circle's, and a sphere behind it would be hidden there, as the post hides the sphere's own rim
(training/preprocess.py _beside_support, docs/interfaces.md step 5). Two frames of the independent
ray-caster (bench/raycast) were refused as "two spheres" by a circle overlapping the sphere:
frame 14 of the `rig` family, seed 410 (a clutter ellipse of the sphere's size cut by the frame's
bottom edge: its rays in the frame 0.44 supported, 10 of its 44 supported rays on the sphere), and
frame 82 of the `rig-photo` family, seed 503 (a motorcycle photo: a circle grown to 0.422, 10 of
its 54 supported rays on the sphere). Both are now answered within 0.5 px and 0.5 % of the truth.
A sphere partly behind the sphere, a fifth of its rim hidden, is still a second sphere, in
Python and in C. The C runtime gives the same circles."""
import json
import subprocess

import cv2
import numpy as np
import pytest

from pihelpers import sphere_frame
from training import preprocess as pp
from v2_raycast_cases import (CAMERA, MODEL, assert_same_circles_in_c, assert_within_limits, params,
                              render_seeded, without_colours)

OVERLAPPING = [(("rig", 14, "23.404_-18.313_11.347.png"), 410),
               (("rig-photo", 82, "-4.913_15.483_18.591.png"), 503)]


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    return render_seeded(tmp_path_factory.mktemp("beside"), OVERLAPPING)


def test_answered_within_limits(frames, monkeypatch):
    p = params()
    imgs = assert_within_limits(frames, p)
    # with the rays on the sphere's disc supporting the other circle: two spheres (what this guards;
    # without the colours' test, which keeps them answered too)
    without_colours(monkeypatch)
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


def behind_frame(path):
    """Two discs with texture blobs, the one on the left in front hiding a fifth of the other's
    rim (pihelpers.sphere_frame twice)."""
    back = sphere_frame(cx=420, cy=256, r=110, seed=41)
    front = sphere_frame(cx=250, cy=256, r=110, seed=42)
    yy, xx = np.mgrid[0:512, 0:640]
    cv2.imwrite(str(path), np.where(((xx - 250) ** 2 + (yy - 256) ** 2 <= 110 ** 2)[..., None], front, back))
    return path


def test_a_sphere_behind_is_still_a_second_one(tmp_path, poseinfer, timeout_scale, monkeypatch):
    path = behind_frame(tmp_path / "behind.png")
    seen = []
    beside = pp._beside_support
    monkeypatch.setattr(pp, "_beside_support",
                        lambda img, dirs, a, b, p: seen.append((b[3], beside(img, dirs, a, b, p))) or seen[-1][1])
    with pytest.raises(pp.NoSphere, match="two spheres") as err:
        pp.find_sphere(cv2.imread(str(path), cv2.IMREAD_COLOR), params())
    # judged by the whole-circle rule, its rays on the front disc counted as without
    assert len(seen) == 1 and 0.42 <= seen[0][1] < seen[0][0], seen
    proc = subprocess.run([str(poseinfer), "--model", str(MODEL), str(path)], capture_output=True, text=True,
                          timeout=120 * timeout_scale)
    assert json.loads(proc.stdout.splitlines()[0]).get("error") == "preprocess: " + str(err.value), proc.stdout
