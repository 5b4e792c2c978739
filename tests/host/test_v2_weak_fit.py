"""sphere-crop-v2: a fit that settles on a black texture band just inside a dark limb (its
support weak) is tried again from larger circles and moves out to the rim. Three frames of the
independent ray-caster (bench/raycast, seed 0: `rig` frame 9, `rig-unseen` frame 17 and `shifts`
frame 76 of build/realscene-final) where the first fit was 3.4, 3.6 and 7.2 px off (the last
one 2.2 px after one try, within the limits only after a second try from there): now within
0.5 px and 0.5 % of the truth, and the C runtime gives the same circle as Python."""
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import cv2
import pytest

from textures.generate import render as texture_rgb
from training import preprocess as pp
from training.export import read_metadata

REPO = Path(__file__).resolve().parents[2]
MODEL = REPO / "training" / "models" / "Texture_3_color.onnx"
CAMERA = {"width": 640, "height": 512, "focal_mm": 16.0, "pixel_mm": 0.0096, "distance_mm": 250.0,
          "sphere_diameter_mm": 40.0}
FRAMES = [("rig", 9), ("rig-unseen", 17), ("shifts", 76)]


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    """[(path, true circle in OpenCV coordinates)] of the ray-caster frames."""
    sys.path.insert(0, str(REPO / "bench"))
    from raycast import camera, frames as rc_frames, render
    d = tmp_path_factory.mktemp("weak_fit")
    tex_path = d / "Texture_3_color.png"
    cv2.imwrite(str(tex_path), texture_rgb(3, "color")[:, :, ::-1])
    tex = render.load_texture(str(tex_path))
    cam = camera.load_camera(None)
    out = []
    for family, index in FRAMES:
        name, png, truth = rc_frames.make_frame(family, 0, index, cam, tex)
        path = d / f"{family}_{name}"
        path.write_bytes(png)
        cx, cy, r = truth["circle"]
        out.append((path, (cx - 0.5, cy - 0.5, r)))
    return out


def _err(found, truth):
    return math.hypot(found[0] - truth[0], found[1] - truth[1]), abs(found[2] / truth[2] - 1) * 100


def test_weak_fit_moves_out_to_the_rim(frames, monkeypatch):
    p = pp.params(read_metadata(MODEL)["spherepose.preprocess"], model=MODEL.name)
    for path, truth in frames:
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        ec, er = _err(pp.find_sphere(img, p, CAMERA), truth)
        assert ec <= 0.5 and er <= 0.5, (path.name, ec, er)
    # without the second try the fit stays on the band (what this guards)
    monkeypatch.setattr(pp, "_grow", lambda img, dirs, fit, p: fit)
    for path, truth in frames:
        ec, _ = _err(pp.find_sphere(cv2.imread(str(path), cv2.IMREAD_COLOR), p, CAMERA), truth)
        assert ec > 2.0, (path.name, ec)


def test_weak_fit_same_circle_in_c(frames, tmp_path):
    exe = Path(os.environ.get("POSEINFER", REPO / "host" / "build" / "poseinfer"))
    assert exe.exists(), f"{exe} is not built (make -C host)"
    cam = tmp_path / "camera.json"
    cam.write_text(json.dumps(CAMERA))
    p = pp.params(read_metadata(MODEL)["spherepose.preprocess"], model=MODEL.name)
    for path, _ in frames:
        cx, cy, r, _ = pp.find_sphere(cv2.imread(str(path), cv2.IMREAD_COLOR), p, CAMERA)
        proc = subprocess.run([str(exe), "--model", str(MODEL), "--camera-file", str(cam), str(path)],
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stdout + proc.stderr
        line = json.loads(proc.stdout.splitlines()[0])
        assert line["circle"] == [round(cx + 0.5, 3), round(cy + 0.5, 3), round(r, 3)], (path.name, line)
