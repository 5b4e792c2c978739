"""Shared by the sphere-crop-v2 regression tests on frames of the independent ray-caster
(test_v2_weak_fit.py, test_v2_rim.py): the shipped model's localisation parameters, the reference
camera file, the frames made again from (family, seed 0, index) as build/realscene-final holds
them, the error measure of docs/bench/localise.md, and the check that the C runtime finds the
circle Python finds."""
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import cv2

from textures.generate import render as texture_rgb
from training import preprocess as pp
from training.export import read_metadata

REPO = Path(__file__).resolve().parents[2]
MODEL = REPO / "training" / "models" / "Texture_3_color.onnx"
CAMERA = {"width": 640, "height": 512, "focal_mm": 16.0, "pixel_mm": 0.0096, "distance_mm": 250.0,
          "sphere_diameter_mm": 40.0}


def params():
    """sphere-crop-v2's parameters as the shipped model carries them."""
    return pp.params(read_metadata(MODEL)["spherepose.preprocess"], model=MODEL.name)


def render_frames(folder, cases):
    """cases: (family, index[, expected file name]) of seed 0. Returns [(path, true circle in
    OpenCV coordinates)]."""
    sys.path.insert(0, str(REPO / "bench"))
    from raycast import camera, frames as rc_frames, render
    tex_path = Path(folder) / "Texture_3_color.png"
    cv2.imwrite(str(tex_path), texture_rgb(3, "color")[:, :, ::-1])
    tex = render.load_texture(str(tex_path))
    cam = camera.load_camera(None)
    out = []
    for family, index, *want in cases:
        name, png, truth = rc_frames.make_frame(family, 0, index, cam, tex)
        assert not want or name == want[0], (family, index, name)
        path = Path(folder) / f"{family}_{name}"
        path.write_bytes(png)
        cx, cy, r = truth["circle"]
        out.append((path, (cx - 0.5, cy - 0.5, r)))
    return out


def circle_error(found, truth):
    """(centre error in px, radius error in %)."""
    return math.hypot(found[0] - truth[0], found[1] - truth[1]), abs(found[2] / truth[2] - 1) * 100


def assert_same_circles_in_c(paths, tmp_path):
    """poseinfer (POSEINFER, default host/build/poseinfer) prints the circle Python finds."""
    exe = Path(os.environ.get("POSEINFER", REPO / "host" / "build" / "poseinfer"))
    assert exe.exists(), f"{exe} is not built (make -C host)"
    cam = Path(tmp_path) / "camera.json"
    cam.write_text(json.dumps(CAMERA))
    p = params()
    for path in paths:
        cx, cy, r, _ = pp.find_sphere(cv2.imread(str(path), cv2.IMREAD_COLOR), p, CAMERA)
        proc = subprocess.run([str(exe), "--model", str(MODEL), "--camera-file", str(cam), str(path)],
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stdout + proc.stderr
        line = json.loads(proc.stdout.splitlines()[0])
        assert line["circle"] == [round(cx + 0.5, 3), round(cy + 0.5, 3), round(r, 3)], (path.name, line)
