"""Renderer, camera files, randomisation and `sim render`."""
import subprocess
import sys

import cv2
import numpy as np
import pytest

from sim.camera import Camera, CameraError, load_camera
from sim.randomize import PRESET, Randomization, check, render_frame
from sim.render import DEFAULT_BACKGROUND, Renderer, TextureError, load_texture
from training.preprocess import find_sphere, params


@pytest.fixture(scope="module")
def renderer(stripe_rgb):
    return Renderer(stripe_rgb)


def bgr(rgb):
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)


# ---- camera files -------------------------------------------------------------

def test_camera_defaults_and_geometry(tmp_path):
    cam = load_camera(None)
    assert cam == Camera() and cam.width == 640 and cam.focal_px == pytest.approx(1666.667, abs=1e-3)
    p = tmp_path / "c.json"
    p.write_text('{"width": 320, "distance_mm": 300}')
    c = load_camera(str(p))
    assert (c.width, c.height, c.distance_mm, c.focal_mm) == (320, 512, 300.0, 16.0)
    # conventions.md projection, e.g. body point (10, 0, 17.32) at pose 0
    assert np.allclose(cam.project([[10.0, 0.0, 17.320508]]), [[391.629, 256.0]], atol=1e-3)


@pytest.mark.parametrize("text,words", [
    ('{"widht": 640}', ["unknown key 'widht'"]),
    ('{"width": -5}', ["'width'", "positive"]),
    ('{"width": 640.5}', ["'width'", "whole number"]),
    ('{"focal_mm": "16"}', ["'focal_mm'", "number"]),
    ('{"focal_mm": true}', ["'focal_mm'", "number"]),
    ('{"distance_mm": 10}', ["'distance_mm'", "inside the sphere"]),
    ('[1, 2]', ["JSON object"]),
    ('{"width": 640', ["not valid JSON"]),
])
def test_bad_camera_files_name_file_and_key(tmp_path, text, words):
    p = tmp_path / "cam.json"
    p.write_text(text)
    with pytest.raises(CameraError) as e:
        load_camera(str(p))
    assert str(p) in str(e.value)
    for w in words:
        assert w in str(e.value)


def test_missing_camera_file(tmp_path):
    with pytest.raises(CameraError, match="cannot read camera file"):
        load_camera(str(tmp_path / "nope.json"))


# ---- the renderer -------------------------------------------------------------

def test_sphere_where_the_camera_model_puts_it(renderer):
    """The lit default render: sphere-crop-v1 finds the sphere at the image centre, 267 px across."""
    p = params()
    for pose in [(0, 0, 0), (30, -30, 30), (-17.5, 8.25, 3)]:
        img = renderer.render(pose)
        assert img.shape == (512, 640, 3) and img.dtype == np.uint8
        assert tuple(img[0, 0]) == DEFAULT_BACKGROUND
        cx, cy, r, bg = find_sphere(bgr(img), p)
        assert abs(cx + 0.5 - 320) <= 1.0 and abs(cy + 0.5 - 256) <= 1.0, (pose, cx, cy)
        # 40 mm at 230 mm from the camera's centre of projection: r = f_px * R / sqrt(D^2 - R^2)
        r_true = 1666.667 * 20 / np.sqrt(250 ** 2 - 20 ** 2)
        assert abs(r - r_true) <= 1.5, (pose, r, r_true)


def test_frames_do_not_depend_on_earlier_frames(renderer, stripe_rgb):
    a = renderer.render((10, 20, 30))
    renderer.render((-5, 0, 0), background=(0, 0, 0), offset_px=(9, 9), scale=1.2)
    assert np.array_equal(a, renderer.render((10, 20, 30)))
    fresh = Renderer(stripe_rgb)
    assert np.array_equal(a, fresh.render((10, 20, 30)))


def _silhouette(img):
    """(cx, cy, r) of the pixels away from the default background: centroid and area radius."""
    ys, xs = np.nonzero(np.abs(img.astype(int) - np.array(DEFAULT_BACKGROUND)).max(axis=2) > 20)
    return xs.mean(), ys.mean(), np.sqrt(len(xs) / np.pi)


def test_offset_and_scale_move_the_principal_point_and_focal_length(renderer):
    # Measured on the silhouette itself: this is the renderer's geometry, not a localiser's.
    cx0, cy0, r0 = _silhouette(renderer.render((0, 0, 0)))
    cx, cy, r = _silhouette(renderer.render((0, 0, 0), offset_px=(12, -7), scale=1.1))
    assert abs(cx - cx0 - 12) <= 0.2 and abs(cy - cy0 + 7) <= 0.2
    assert abs(r / r0 - 1.1) < 0.005


def test_rotation_changes_the_view_but_not_the_silhouette(renderer):
    a, b = renderer.render((0, 0, 0)), renderer.render((0, 0, 3))
    assert np.abs(a.astype(int) - b).mean() > 1.0


def test_texture_must_be_equirectangular(tmp_path):
    p = tmp_path / "square.png"
    cv2.imwrite(str(p), np.zeros((64, 64, 3), np.uint8))
    with pytest.raises(TextureError, match="square.png.*twice as wide"):
        load_texture(str(p))
    with pytest.raises(TextureError, match="not found"):
        load_texture(str(tmp_path / "none.png"))
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"not a png")
    with pytest.raises(TextureError, match="junk.png"):
        load_texture(str(junk))


# ---- randomisation --------------------------------------------------------------

def test_randomisation_off_changes_nothing(renderer):
    rng = np.random.default_rng(0)
    assert np.array_equal(render_frame(renderer, (1, 2, 3), Randomization(), rng), renderer.render((1, 2, 3)))


def test_randomised_frames_are_seeded_and_still_croppable(renderer):
    def frame(i):
        return render_frame(renderer, (5, -5, 5), PRESET, np.random.default_rng([7, 2, i]))
    assert np.array_equal(frame(3), frame(3))
    assert not np.array_equal(frame(3), frame(4))
    r_true = 1666.667 * 20 / np.sqrt(250 ** 2 - 20 ** 2)
    for i in range(6):
        cx, cy, r, _ = find_sphere(bgr(frame(i)))
        assert abs(cx + 0.5 - 320) <= PRESET.offset_px + 2 and abs(cy + 0.5 - 256) <= PRESET.offset_px + 2
        assert abs(r / r_true - 1) <= PRESET.scale + 0.02


def test_randomisation_ranges_are_checked():
    with pytest.raises(ValueError, match="exposure"):
        check(Randomization(exposure=(1.2, 0.8)))
    with pytest.raises(ValueError, match="noise"):
        check(Randomization(noise=-1))
    with pytest.raises(ValueError, match="scale"):
        check(Randomization(scale=0.7))


# ---- sim render -------------------------------------------------------------------

def test_sim_render_writes_the_frame(tmp_path, texture_png, small_camera_json):
    out = tmp_path / "f.png"
    r = subprocess.run([sys.executable, "-m", "sim.cli", "render", "--texture", texture_png, "--camera",
                        small_camera_json, "--pose", "10", "-20", "30", "--background", "50,60,70",
                        "--out", str(out)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    img = cv2.imread(str(out))[:, :, ::-1]
    direct = Renderer(texture_png, load_camera(small_camera_json), background=(50, 60, 70)).render((10, -20, 30))
    assert np.array_equal(img, direct)
    assert [p.name for p in tmp_path.iterdir()] == ["f.png"]  # no temporary left


@pytest.mark.parametrize("extra,words", [
    (["--pose", "1", "2", "--out", "X/f.png"], ["--pose"]),
    (["--pose", "1", "2", "nan", "--out", "X/f.png"], ["finite"]),
    (["--pose", "1", "2", "3", "--background", "1,2", "--out", "X/f.png"], ["R,G,B"]),
    (["--pose", "1", "2", "3", "--out", "X/missing/f.png"], ["does not exist"]),
    (["--pose", "1", "2", "3", "--out", "X/f.jpg"], [".png"]),
])
def test_sim_render_bad_input(tmp_path, texture_png, extra, words):
    extra = [e.replace("X/", f"{tmp_path}/") for e in extra]
    r = subprocess.run([sys.executable, "-m", "sim.cli", "render", "--texture", texture_png, *extra],
                       capture_output=True, text=True)
    assert r.returncode != 0
    for w in words:
        assert w in r.stderr


def test_every_command_has_help():
    for cmd in ([], ["render"], ["dataset"], ["vcam"]):
        r = subprocess.run([sys.executable, "-m", "sim.cli", *cmd, "--help"], capture_output=True, text=True)
        assert r.returncode == 0 and "usage: sim" in r.stdout
