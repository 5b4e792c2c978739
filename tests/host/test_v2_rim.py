"""sphere-crop-v2: the found circle's radius is moved from the steepest colour step to the rim
(training/preprocess.py _rim), and a weakly supported sphere is refitted through the outermost
edges near it (_outermost). Two frames of the independent ray-caster (bench/raycast, seed 0, as
in build/realscene-final): `rig` frame 84 (a headlight-lit limb on a dark backdrop: the
steepest step lies inside the rim) was fitted 0.69 % small, `shifts` frame 83 (an arc of the
rim without a colour step, a band inside it) 0.83 px off; both are now within 0.5 px and 0.5 %
of the truth, and the C runtime gives the same circles as Python."""
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
FRAMES = [("rig", 84, "-14.463_5.02_-17.423.png"), ("shifts", 83, "-9.616_0.909_20.38.png")]


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    """[(path, true circle in OpenCV coordinates)] of the ray-caster frames."""
    sys.path.insert(0, str(REPO / "bench"))
    from raycast import camera, frames as rc_frames, render
    d = tmp_path_factory.mktemp("rim")
    tex_path = d / "Texture_3_color.png"
    cv2.imwrite(str(tex_path), texture_rgb(3, "color")[:, :, ::-1])
    tex = render.load_texture(str(tex_path))
    cam = camera.load_camera(None)
    out = []
    for family, index, want in FRAMES:
        name, png, truth = rc_frames.make_frame(family, 0, index, cam, tex)
        assert name == want
        path = d / f"{family}_{name}"
        path.write_bytes(png)
        cx, cy, r = truth["circle"]
        out.append((path, (cx - 0.5, cy - 0.5, r)))
    return out


def _err(found, truth):
    return math.hypot(found[0] - truth[0], found[1] - truth[1]), abs(found[2] / truth[2] - 1) * 100


def test_rim_and_outermost_edges(frames, monkeypatch):
    p = pp.params(read_metadata(MODEL)["spherepose.preprocess"], model=MODEL.name)
    imgs = [cv2.imread(str(path), cv2.IMREAD_COLOR) for path, _ in frames]
    for img, (path, truth) in zip(imgs, frames):
        ec, er = _err(pp.find_sphere(img, p, CAMERA), truth)
        assert ec <= 0.5 and er <= 0.5, (path.name, ec, er)
    # without the refit the `shifts` frame stays off centre (what this guards)
    monkeypatch.setattr(pp, "_outermost", lambda img, dirs, fit, p: fit)
    ec, _ = _err(pp.find_sphere(imgs[1], p, CAMERA), frames[1][1])
    assert ec > 0.7, ec
    # without either, the `rig` frame's radius is the steepest step's, too small
    monkeypatch.setattr(pp, "_rim", lambda img, dirs, fit, p: fit[:3])
    found = pp.find_sphere(imgs[0], p, CAMERA)
    assert found[2] < frames[0][1][2] and _err(found, frames[0][1])[1] > 0.6, found


def test_same_circles_in_c(frames, tmp_path):
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
