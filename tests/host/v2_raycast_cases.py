"""Shared by the sphere-crop-v2 regression tests on frames of the independent ray-caster
(test_v2_weak_fit.py, test_v2_rim.py, test_v2_unanswered.py, test_v2_limb.py, test_v2_tangent.py,
test_v2_wide.py, test_v2_first_peak.py, test_v2_rim_near.py, ...): the shipped model's
localisation parameters, the reference camera file, the frames made again from (family, seed,
index) (seed 0's as build/realscene-final holds them), the error measure of
docs/bench/localise.md, and the check that the C runtime finds the circle Python finds."""
import json
import math
import subprocess
import sys
from pathlib import Path

import cv2

from sim.camera import REFERENCE as CAMERA
from textures.generate import render as texture_rgb, write_png_atomic
from training import preprocess as pp
from training import refine as rf
from training.export import onnx_session, read_metadata

REPO = Path(__file__).resolve().parents[2]
MODEL = REPO / "training" / "models" / "Texture_3_color.onnx"

# Frames whose printed circle is the rim found from the refined circle (test_v2_rim_check.py):
# ((family, index, file name), seed); the localisation's circle is 0.9-1.9 px off on each.
RIM_CHECK_CASES = [(("edge", 95, "-9.272_9.416_12.572.png"), 426),
                   (("edge", 78, "2.571_10.142_24.749.png"), 439),
                   (("rig-unseen", 64, "-6.669_-13.109_12.519.png"), 439)]


def params():
    """sphere-crop-v2's parameters as the shipped model carries them."""
    return pp.params(read_metadata(MODEL)["spherepose.preprocess"], model=MODEL.name)


def render_frames(folder, cases, seed=0):
    """cases: (family, index[, expected file name]) of `seed` (0: build/realscene-final's).
    Returns [(path, true circle in OpenCV coordinates, None without a sphere)]."""
    sys.path.insert(0, str(REPO / "bench"))
    from raycast import camera, frames as rc_frames, render
    tex_path = Path(folder) / "Texture_3_color.png"
    write_png_atomic(texture_rgb(3, "color"), str(tex_path))
    tex = render.load_texture(str(tex_path))
    cam = camera.load_camera(None)
    out = []
    for family, index, *want in cases:
        name, png, truth = rc_frames.make_frame(family, seed, index, cam, tex)
        assert not want or name == want[0], (family, index, name)
        path = Path(folder) / f"{family}_{name}"
        path.write_bytes(png)
        c = truth["circle"]  # None for a frame without the sphere (`refuse`, kind none)
        out.append((path, None if c is None else (c[0] - 0.5, c[1] - 0.5, c[2])))
    return out



def render_seeded(folder, cases):
    """render_frames for ((family, index[, name]), seed) pairs, in their order."""
    return [f for case, seed in cases for f in render_frames(folder, [case], seed)]


def assert_within_limits(frames, p):
    """Every frame's circle within 0.5 px and 0.5 % of its truth (docs/bench/localise.md's
    limits); returns the decoded frames, for the same checks with a step switched off."""
    imgs = [cv2.imread(str(path), cv2.IMREAD_COLOR) for path, _ in frames]
    for img, (path, truth) in zip(imgs, frames):
        ec, er = circle_error(pp.find_sphere(img, p, CAMERA), truth)
        assert ec <= 0.5 and er <= 0.5, (path.name, ec, er)
    return imgs

def assert_off_centre(imgs, frames, p, px):
    """Every frame's circle more than px off its true centre: what a regression test's frames
    show with the step it guards switched off (imgs: assert_within_limits's)."""
    for img, (path, truth) in zip(imgs, frames):
        ec, _ = circle_error(pp.find_sphere(img, p, CAMERA), truth)
        assert ec > px, (path.name, ec)


def without_colours(monkeypatch):
    """Every second circle's colours taken for the sphere's (_alike): a clutter circle beside the
    sphere is then judged by the other tests alone. The colours' test also keeps many of the frames
    that an earlier rule about second circles keeps answered; a test of such a rule switches it off
    to show what its own rule mends."""
    monkeypatch.setattr(pp, "_alike", lambda img, dirs, a, b: True)


def without_rim_refit(monkeypatch):
    """The sphere's circle not refitted through the rims (_through_rims): its centre stays where
    the refit through the outermost edges put it and only its radius moves to the rim. That refit
    corrects the lean of a circle fitted through the steps inside a dark limb, as several earlier
    steps do; a test of one of those steps switches it off to show what its own step mends."""
    monkeypatch.setattr(pp, "_through_rims", lambda xs, ys, r, p: (0.0, 0.0, r))


def without_wide_gap_retry(monkeypatch):
    """No second search of a frame refused as without a sphere (_find_sphere_v2's search again with
    the wide search's coarse gap, _search's lit_only): it reaches some of the frames that earlier
    steps for a refused frame mend; a test of such a step switches it off to show what its own step
    mends."""
    search = pp._search

    def first_only(frame, p, rmin, rmax, gap_r, fits_out, cov_out, lit_only=False):
        if lit_only:
            raise pp.NoSphere(pp.NO_SPHERE)
        return search(frame, p, rmin, rmax, gap_r, fits_out, cov_out)
    monkeypatch.setattr(pp, "_search", first_only)


def without_rim_choice(monkeypatch):
    """The sphere's circle chosen as it was before its rims judged it (_final_circle): the wider
    band's circle when better supported (_wide), then the last step from it. That choice mends
    some of the frames an earlier step mends too; a test of such a step switches it off to show
    what its own step mends."""
    def by_support(img, dirs, a, p, cov=None):   # cov left empty: these tests read no covariance
        w = pp._wide(img, dirs, a, *pp._refit_rays(img, dirs, a, p), p)
        return pp._last_step(*pp._refit_rays(img, dirs, w, p), dirs, w, p)[0]
    monkeypatch.setattr(pp, "_final_circle", by_support)


def circle_error(found, truth):
    """(centre error in px, radius error in %)."""
    return math.hypot(found[0] - truth[0], found[1] - truth[1]), abs(found[2] / truth[2] - 1) * 100


def poseinfer_lines(poseinfer, paths, tmp_path, options=(), timeout_scale=1.0, rc=0):
    """poseinfer's result lines (conftest's fixture) for the frames, one run with the reference
    camera file and `options`: a line for every frame, in order, and exit status rc (0: every
    frame answered; 1: some refused)."""
    cam = Path(tmp_path) / "camera.json"
    cam.write_text(json.dumps(CAMERA))
    proc = subprocess.run([str(poseinfer), "--model", str(MODEL), "--camera-file", str(cam), *options]
                          + [str(path) for path in paths], capture_output=True, text=True,
                          timeout=120 * timeout_scale)
    assert proc.returncode == rc, proc.stdout + proc.stderr
    lines = [json.loads(s) for s in proc.stdout.splitlines()]
    assert [line["file"] for line in lines] == [str(path) for path in paths], proc.stdout
    return lines


def assert_same_circles_in_c(poseinfer, paths, tmp_path, timeout_scale=1.0):
    """poseinfer (conftest's fixture) prints the circle Python finds, for every frame of one run:
    unrefined, as a confident refined answer's circle can be the rim found from the refined
    circle instead (test_v2_rim_check.py)."""
    lines = poseinfer_lines(poseinfer, paths, tmp_path, ("--no-refine",), timeout_scale)
    p = params()
    for path, line in zip(paths, lines):
        cx, cy, r, _ = pp.find_sphere(cv2.imread(str(path), cv2.IMREAD_COLOR), p, CAMERA)
        assert line["circle"] == [round(cx + 0.5, 3), round(cy + 0.5, 3), round(r, 3)], (path.name, line)


def python_results(paths, lines):
    """The Python reference's result line (training/refine.py Refiner, with the localisation's
    covariance) for each frame, from the C side's network angles (poseinfer_lines' `net`, run
    with --timings), so that only refinement and the printed circle are compared."""
    meta = read_metadata(MODEL)
    sess = onnx_session(MODEL, 1)
    ref = rf.Refiner(meta, CAMERA)
    out = []
    for path, line in zip(paths, lines):
        und, circle, _, cov = rf.network_estimate(sess, meta, cv2.imread(str(path)), CAMERA)
        out.append((ref(und, circle, tuple(line["net"]), cov=cov), cov))
    return out
