"""sphere-crop-v2: the found circle's radius is moved from the steepest colour step to the rim
(training/preprocess.py _rim). On a limb that darkens towards the rim, under blur, the steepest
step lies up to a pixel inside the outline: `rig` frame 84 of the independent ray-caster
(bench/raycast, seed 0, as in build/realscene-final; a headlight-lit limb on a dark backdrop)
was fitted 0.69 % small; its radius is now within 0.5 % of the truth (centre within 0.5 px), and
the C runtime gives the same circle as Python."""
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
FAMILY, INDEX, NAME = "rig", 84, "-14.463_5.02_-17.423.png"


@pytest.fixture(scope="module")
def frame(tmp_path_factory):
    """(path, true circle in OpenCV coordinates) of the ray-caster frame."""
    sys.path.insert(0, str(REPO / "bench"))
    from raycast import camera, frames as rc_frames, render
    d = tmp_path_factory.mktemp("rim")
    tex_path = d / "Texture_3_color.png"
    cv2.imwrite(str(tex_path), texture_rgb(3, "color")[:, :, ::-1])
    tex = render.load_texture(str(tex_path))
    name, png, truth = rc_frames.make_frame(FAMILY, 0, INDEX, camera.load_camera(None), tex)
    assert name == NAME
    path = d / f"{FAMILY}_{name}"
    path.write_bytes(png)
    cx, cy, r = truth["circle"]
    return path, (cx - 0.5, cy - 0.5, r)


def _err(found, truth):
    return math.hypot(found[0] - truth[0], found[1] - truth[1]), abs(found[2] / truth[2] - 1) * 100


def test_radius_at_the_rim(frame, monkeypatch):
    path, truth = frame
    p = pp.params(read_metadata(MODEL)["spherepose.preprocess"], model=MODEL.name)
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    ec, er = _err(pp.find_sphere(img, p, CAMERA), truth)
    assert ec <= 0.5 and er <= 0.5, (ec, er)
    # at the steepest step the radius is too small (what this guards)
    monkeypatch.setattr(pp, "_rim", lambda img, dirs, fit, p: fit[:3])
    found = pp.find_sphere(img, p, CAMERA)
    assert found[2] < truth[2] and _err(found, truth)[1] > 0.6, found


def test_rim_same_circle_in_c(frame, tmp_path):
    exe = Path(os.environ.get("POSEINFER", REPO / "host" / "build" / "poseinfer"))
    assert exe.exists(), f"{exe} is not built (make -C host)"
    path, _ = frame
    cam = tmp_path / "camera.json"
    cam.write_text(json.dumps(CAMERA))
    p = pp.params(read_metadata(MODEL)["spherepose.preprocess"], model=MODEL.name)
    cx, cy, r, _ = pp.find_sphere(cv2.imread(str(path), cv2.IMREAD_COLOR), p, CAMERA)
    proc = subprocess.run([str(exe), "--model", str(MODEL), "--camera-file", str(cam), str(path)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    line = json.loads(proc.stdout.splitlines()[0])
    assert line["circle"] == [round(cx + 0.5, 3), round(cy + 0.5, 3), round(r, 3)], line
