"""scripts/sphere_check.py: what the sphere finder sees in a user's frames, and why a frame is
refused. Frames of the independent ray-caster (bench/raycast) and drawn ones."""
import importlib.util
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from sim.camera import REFERENCE as CAMERA
from textures.generate import render as texture_rgb, write_png_atomic
from training import preprocess as pp
from training.export import read_metadata

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "scripts" / "sphere_check.py"
MODEL = REPO / "training" / "models" / "Texture_3_color.onnx"

spec = importlib.util.spec_from_file_location("sphere_check", SCRIPT)
sc = importlib.util.module_from_spec(spec)
spec.loader.exec_module(sc)


@pytest.fixture(scope="module")
def p():
    return pp.params(read_metadata(MODEL)["spherepose.preprocess"], model=MODEL.name)


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    """(path, true circle in OpenCV coordinates) of a `rig` frame the finder answers (seed 505
    frame 0) and a `refuse` frame whose sphere is 38 % outside the frame (seed 503 frame 48)."""
    sys.path.insert(0, str(REPO / "bench"))
    from raycast import camera, frames as rc_frames, render
    folder = tmp_path_factory.mktemp("sphere_check")
    tex_path = folder / "Texture_3_color.png"
    write_png_atomic(texture_rgb(3, "color"), str(tex_path))
    tex = render.load_texture(str(tex_path))
    cam = camera.load_camera(None)
    out = []
    for family, seed, index in (("rig", 505, 0), ("refuse", 503, 48)):
        name, png, truth = rc_frames.make_frame(family, seed, index, cam, tex)
        path = folder / f"{family}_{name}"
        path.write_bytes(png)
        c = truth["circle"]
        out.append((path, (c[0] - 0.5, c[1] - 0.5, c[2])))
    return out


def _disk_frame():
    """A grey disk (r 120 at (320, 256), value 100, dark bands inside short of its rim) on a backdrop as bright as
    it on the left half and dark on the right; at the bottom right a backdrop of 70 with bright
    rings 2 px apart from 3 px beyond the rim, and dark bands inside up to 2 px from it: rays to
    the right find the rim, to the left it is faint, at the rings crowded (a weak rim between the
    texture's edges and stronger ones beyond it)."""
    h, w, cx, cy, r = 512, 640, 320.0, 256.0, 120.0
    y, x = np.mgrid[0:h, 0:w]
    img = np.where(x < cx, 100, 20).astype(np.float64)
    inside = np.hypot(x - cx, y - cy) <= r
    bands = (np.floor((x - cx) / 20) % 2 == 0) & (np.hypot(x - cx, y - cy) < 0.8 * r)
    img[inside] = np.where(bands[inside], 40, 100)
    ang = np.degrees(np.arctan2(y - cy, x - cx))
    d = np.hypot(x - cx, y - cy)
    sector = (d > r) & (d <= r + 12) & (ang > 30) & (ang < 60)
    img[sector] = np.where((d[sector] >= r + 3) & (np.floor((d[sector] - r) / 2) % 2 == 0), 230, 70)
    edge = (d >= r - 8) & (d <= r - 2) & (ang > 30) & (ang < 60)
    img[edge] = np.where(np.floor((d[edge] - r) / 2) % 2 == 0, 40, 100)
    img = cv2.GaussianBlur(img, (0, 0), 0.8)
    return np.repeat(np.clip(img + 0.5, 0, 255).astype(np.uint8)[:, :, None], 3, axis=2), (cx, cy, r)


def test_rays_told_apart(p):
    img, circle = _disk_frame()
    kinds = sc.ray_kinds(img, circle, p)
    k = len(kinds)
    by_angle = {i * 360.0 / k: kind for i, kind in enumerate(kinds)}

    def most(lo, hi):
        got = [kind for a, kind in by_angle.items() if lo <= a <= hi]
        return max(set(got), key=got.count), got.count(max(set(got), key=got.count)) / len(got)

    assert most(95, 265) == ("faint", 1.0)   # the left half: backdrop as bright as the disk's edge
    assert most(35, 55) == ("crowded", 1.0)  # the rings beyond the rim
    kind, part = most(275, 360)
    assert kind == "rim" and part >= 0.9     # the dark right half
    assert sc.where(kinds, "faint") == "left"
    first, last = sc.arcs(kinds, "crowded")[0]
    assert first == pytest.approx(30.0, abs=3.0) and last == pytest.approx(60.0, abs=3.0)


def test_advice_says_why(p):
    img, circle = _disk_frame()
    kinds = sc.ray_kinds(img, circle, p)
    faint = sc.advice("no sphere found in frame", circle, 0.3, kinds, p, img, None)
    assert "the rim is faint on" in faint[0] and "(left" in faint[0] and "backdrop darker or brighter" in faint[0]
    assert faint[0].startswith("if the best circle lies on your sphere, a frame needs 42 %")
    assert faint[1].startswith("if it does not, the sphere was not found at all")
    margin = sc.advice(None, circle, p["min_support"] + 0.05, kinds, p, img, None)
    assert margin[0].startswith("little margin: a frame is refused below 42 %")
    assert sc.advice(None, circle, p["min_support"] + sc.MARGIN, kinds, p, img, None) == []
    assert "whole sphere is in the frame" in sc.advice("sphere cut by the frame edge (20 % ...)", circle, 0.5,
                                                      kinds, p, img, None)[0]


def test_frames_checked_and_drawn(frames, p, tmp_path):
    (answered, truth), (cut, _) = frames
    bad = tmp_path / "corrupt.png"
    bad.write_bytes(b"\x89PNG\r\n\x1a\n not an image")
    out = tmp_path / "out"
    cam = tmp_path / "camera.json"
    cam.write_text(json.dumps(CAMERA))
    proc = subprocess.run([sys.executable, str(SCRIPT), "--camera-file", str(cam), "--out", str(out), "--json",
                           str(answered), str(bad), str(cut)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    lines = [json.loads(s) for s in proc.stdout.splitlines()]
    assert [line["file"] for line in lines] == [str(answered), str(bad), str(cut)]
    a, b, c = lines
    # the circle poseinfer prints (conventions' coordinates: OpenCV's plus 0.5), found on most rays
    cx, cy, r, _ = pp.find_sphere(cv2.imread(str(answered)), p, CAMERA)
    assert a["answered"] and a["circle"] == [round(cx + 0.5, 3), round(cy + 0.5, 3), round(r, 3)]
    assert math.hypot(cx - truth[0], cy - truth[1]) <= 0.5 and a["rim"] > 0.8 and a["advice"] == []
    assert "cannot decode image" in b["error"]
    assert not c["answered"] and c["error"].startswith("sphere cut by the frame edge")
    assert "whole sphere is in the frame" in c["advice"][0]
    drawn = sorted(f.name for f in out.iterdir())
    assert drawn == sorted([f"{cut.stem}_check.png", f"{answered.stem}_check.png"])
    img = cv2.imread(str(out / f"{answered.stem}_check.png"))
    assert img.shape[1] == 640 and img.shape[0] > 512  # the words below the frame


def test_camera_file_of_another_size(frames, tmp_path, capsys):
    (answered, _), _ = frames
    cam = tmp_path / "near.json"
    cam.write_text(json.dumps({**CAMERA, "distance_mm": CAMERA["distance_mm"] * 0.6}))
    assert sc.main(["--camera-file", str(cam), str(answered)]) == 1
    text = capsys.readouterr().out
    assert "refused" in text and "the camera file expects" in text and "distance_mm" in text


def test_usage_errors(tmp_path):
    help_ = subprocess.run([sys.executable, str(SCRIPT), "--help"], capture_output=True, text=True)
    assert help_.returncode == 0 and "faint" in help_.stdout and "crowded" in help_.stdout
    for args, want in ((["--model", str(tmp_path / "none.onnx"), "x.png"], "cannot read the model"),
                       (["--camera-file", str(tmp_path / "none.json"), "x.png"], "camera file"),
                       ([str(tmp_path)], "no image files")):
        proc = subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True)
        assert proc.returncode == 2 and want in proc.stderr, (args, proc.stderr)


def test_summary_of_several_frames(frames, tmp_path, capsys):
    (answered, _), (cut, _) = frames
    bad = tmp_path / "bad name.png"
    bad.write_bytes(b"")
    cam = tmp_path / "camera.json"
    cam.write_text(json.dumps(CAMERA))
    assert sc.main(["--camera-file", str(cam), str(answered), str(cut), str(bad)]) == 1
    lines = capsys.readouterr().out.splitlines()
    assert lines[-2] == f"{bad}: cannot decode image (missing, corrupt or not an 8-bit image)"
    assert re.fullmatch(r"3 frames: 1 answered \(rim found on \d+ % of the rays\), 1 refused, 1 not checked", lines[-1])
    assert sc.main(["--camera-file", str(cam), str(answered)]) == 0
    assert "frames:" not in capsys.readouterr().out  # one frame: no summary


def test_arcs_round_the_circle():
    kinds = ["rim"] * 16
    for i in (14, 15, 0, 1):  # a run through ray 0
        kinds[i] = "faint"
    assert sc.arcs(kinds, "faint") == [(315.0, 382.5)]
    assert sc.where(kinds, "faint") == "right"
    assert sc.where(["faint"] * 16, "faint") == "all round"
    assert sc.arcs([], "faint") == [] and sc.where([], "faint") == ""
    kinds[6:8] = ["crowded"] * 2  # two rays: no arc
    assert sc.arcs(kinds, "crowded") == [] and sc.where(kinds, "crowded") == ""


def test_drawing_names_kept_apart(tmp_path):
    names = set()
    assert [sc.drawing_name(Path(n), names) for n in ("a.png", "a.jpg", "d/a.png", "b.png")] == \
        ["a_check.png", "a_2_check.png", "a_3_check.png", "b_check.png"]


def test_frame_of_another_size(tmp_path, capsys):
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((100, 120, 3), np.uint8))
    cam = tmp_path / "camera.json"
    cam.write_text(json.dumps(CAMERA))
    assert sc.main(["--camera-file", str(cam), str(small)]) == 1
    assert capsys.readouterr().out.strip() == f"{small}: frame is 120x100, the camera file's calibration is for 640x512"
