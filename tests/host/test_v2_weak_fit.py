"""sphere-crop-v2: a fit that settles on a black texture band just inside a dark limb (its
support weak) is tried again from larger circles and moves out to the rim. Three frames of the
independent ray-caster (bench/raycast, seed 0: `rig` frame 9, `rig-unseen` frame 17 and `shifts`
frame 76 of build/realscene-final) where the first fit was 3.4, 3.6 and 7.2 px off (the last
one 2.2 px after one try, within the limits only after a second try from there): now within
0.5 px and 0.5 % of the truth, and the C runtime gives the same circle as Python."""
import cv2
import pytest

from training import preprocess as pp
from v2_raycast_cases import CAMERA, assert_same_circles_in_c, circle_error, params, render_frames

FRAMES = [("rig", 9), ("rig-unseen", 17), ("shifts", 76)]


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    return render_frames(tmp_path_factory.mktemp("weak_fit"), FRAMES)


def test_weak_fit_moves_out_to_the_rim(frames, monkeypatch):
    p = params()
    for path, truth in frames:
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        ec, er = circle_error(pp.find_sphere(img, p, CAMERA), truth)
        assert ec <= 0.5 and er <= 0.5, (path.name, ec, er)
    # the sphere's tangent tries reach the rim from the band too: without them the tries from
    # larger circles alone must (what this guards)
    monkeypatch.setattr(pp, "_tangent", lambda img, dirs, fit, p: fit)
    for path, truth in frames:
        ec, er = circle_error(pp.find_sphere(cv2.imread(str(path), cv2.IMREAD_COLOR), p, CAMERA), truth)
        assert ec <= 0.5 and er <= 0.5, (path.name, ec, er)
    # and without either (nor the wider band's refit after them, which can reach the rim from
    # there as well) the fit stays on the band
    monkeypatch.setattr(pp, "_grow", lambda img, dirs, fit, p, inward=False: fit)
    monkeypatch.setattr(pp, "WIDE_BELOW", 0.0)
    for path, truth in frames:
        ec, _ = circle_error(pp.find_sphere(cv2.imread(str(path), cv2.IMREAD_COLOR), p, CAMERA), truth)
        assert ec > 2.0, (path.name, ec)


def test_weak_fit_same_circle_in_c(frames, tmp_path, poseinfer, timeout_scale):
    assert_same_circles_in_c(poseinfer, [path for path, _ in frames], tmp_path, timeout_scale)
