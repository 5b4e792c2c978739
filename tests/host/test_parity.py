"""Preprocessing parity: the C++ shim (through `poseinfer --dump-tensor`) and
training/preprocess.py give the same network input on the same frames, and
the same angles through the same model (within 0.01 deg).

sphere-crop-v1 (a v1 model): centred, off-centre, partly out of frame, small,
large, gray, upscaled crop, a JPEG, and a rendered frame when the renderer is
there; within 1e-3.
sphere-crop-v2 (a v2 model): rig-like frames (post, clutter, vignetting,
JPEG), gray and BGRA, small and large, a frame through a lens with its
camera file: bit-identical tensors and the same circle; the same errors on
both sides (no sphere, two spheres, cut by the frame edge); the model and
camera-file checks."""
import json
import math
import subprocess

import numpy as np
import pytest

import make_model
from pihelpers import ROOT, dots_texture, sphere_frame
from training import preprocess
from training import rigcomposite as rc

V1 = preprocess.params({"name": "sphere-crop-v1"})
V2 = preprocess.params()

cv2 = pytest.importorskip("cv2")
ort = pytest.importorskip("onnxruntime")

CASES = {
    "centred.png": dict(),
    "offcentre.png": dict(cx=150, cy=400, r=90, seed=11),
    "partly_out.png": dict(cx=600, cy=30, r=120, seed=12),
    "partly_out_left.png": dict(cx=20, cy=300, r=140, seed=17),
    "small.png": dict(h=240, w=320, cx=100, cy=120, r=50, seed=13),
    "large.png": dict(h=1080, w=1920, cx=1000, cy=500, r=400, seed=14),
    "gray.png": dict(gray=True, seed=15),
    "upscaled.png": dict(h=100, w=120, cx=60, cy=50, r=30, seed=16),
    "flat_bg.png": dict(noise=0, bg=(200, 200, 200), seed=18),
    "frame.jpg": dict(seed=19),
}


@pytest.fixture(scope="module")
def parity_frames(tmp_path_factory):
    d = tmp_path_factory.mktemp("parity")
    paths = []
    for name, kw in CASES.items():
        p = d / name
        cv2.imwrite(str(p), sphere_frame(**kw))
        paths.append(p)
    # several blobs and speckles: the largest contour must win on both sides
    img = sphere_frame(seed=30, cx=400, cy=300, r=110)
    cv2.circle(img, (90, 90), 45, (20, 200, 240), -1)
    rng = np.random.default_rng(31)
    for _ in range(40):
        x, y = int(rng.integers(0, 640)), int(rng.integers(0, 512))
        img[y:y + 2, x:x + 3] = 255
    p = d / "blobs.png"
    cv2.imwrite(str(p), img)
    paths.append(p)
    sim = ROOT / ".venv" / "bin" / "sim"
    if sim.exists():
        tex = dots_texture(d / "tex.png")
        p = d / "rendered.png"
        proc = subprocess.run([str(sim), "render", "--texture", str(tex), "--pose", "10", "-5", "20",
                               "--out", str(p)], capture_output=True, timeout=120)
        if proc.returncode == 0:
            paths.append(p)
    return paths


@pytest.fixture(scope="module")
def session(models):
    return ort.InferenceSession(str(models["good"]), providers=["CPUExecutionProvider"])


def test_tensor_and_angles(run, models, parity_frames, session, tmp_path):
    worst_t = worst_a = 0.0
    for p in parity_frames:
        out = tmp_path / (p.name + ".f32")
        r = run("--model", models["good"], "--dump-tensor", out, p)
        assert r.rc == 0, (p, r.stdout, r.stderr)
        py = preprocess.preprocess_file(p, V1)
        c = np.fromfile(out, np.float32)
        assert c.size == py.size, p
        c = c.reshape(py.shape)
        dt = float(np.abs(c - py).max())
        assert dt <= 1e-3, (p.name, dt)
        angles = session.run(["euler_deg"], {"image": py[None]})[0][0]
        line = r.lines[0]
        da = max(abs(line[k] - float(a)) for k, a in zip("xyz", angles))
        assert da <= 0.01, (p.name, line, angles)
        # the sphere itself, too
        cx, cy, rad, _ = preprocess.find_sphere(cv2.imread(str(p), cv2.IMREAD_UNCHANGED), V1)
        assert abs(line["cx"] - cx) < 0.01 and abs(line["cy"] - cy) < 0.01 and abs(line["r"] - rad) < 0.01
        worst_t, worst_a = max(worst_t, dt), max(worst_a, da)
    print(f"parity over {len(parity_frames)} frames: tensor max |diff| {worst_t:.3g}, angles {worst_a:.3g} deg")


def test_no_sphere_on_both_sides(run, models, tmp_path):
    p = tmp_path / "flat.png"
    cv2.imwrite(str(p), np.full((200, 300, 3), 90, np.uint8))
    with pytest.raises(preprocess.NoSphere):
        preprocess.preprocess_file(p, V1)
    r = run("--model", models["good"], "--dump-tensor", tmp_path / "x.f32", p)
    assert r.rc == 1 and "no sphere found in frame" in r.lines[0]["error"]


# ---- sphere-crop-v2 ----------------------------------------------------------------------------

H, W = 512, 640


def rig(seed, cx=300.0, cy=230.0, r=110.0, h=H, w=W, post_angle=None, level=None):
    rng = np.random.default_rng(seed)
    b, wt = rc.drawn_sphere(h, w, cx, cy, r, rng)
    return rc.rig_frame(b, wt, cx, cy, r, rng, post_angle=post_angle, level=level)


LENS = {"width": W, "height": H, "focal_mm": 16.0, "pixel_mm": 0.0096, "distance_mm": 250.0,
        "sphere_diameter_mm": 40.0, "principal_px": [330.0, 250.0], "distortion": [-0.2, 0.08, 0.001, -0.002, 0.0]}


def through_lens(ideal, cam):
    """The frame a camera with cam's distortion delivers of an ideal (pinhole) image."""
    _, f, u0, v0, dist = preprocess.camera_geometry(cam)
    K = np.array([[f, 0, u0], [0, f, v0], [0, 0, 1]])
    h, w = ideal.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    pts = np.stack([xx.ravel(), yy.ravel()], 1)[:, None, :]
    und = cv2.undistortPoints(pts, K, np.array(dist), P=K).reshape(h, w, 2)
    return cv2.remap(ideal, und[..., 0], und[..., 1], cv2.INTER_LINEAR)


@pytest.fixture(scope="module")
def v2_frames(tmp_path_factory):
    """[(path, camera file or None)] of frames v2 must find the sphere in."""
    d = tmp_path_factory.mktemp("parity2")
    out = []

    def put(name, img, cam=None):
        p = d / name
        cv2.imwrite(str(p), img, [cv2.IMWRITE_JPEG_QUALITY, 85] if name.endswith(".jpg") else [])
        out.append((p, cam))

    for i, (cx, cy, r, ang) in enumerate([(300, 230, 110, 90), (150.5, 380.25, 90, 0), (470, 140, 120, 200),
                                          (330, 260, 70, 300), (320, 256, 134, 60)]):
        put(f"rig{i}.png", rig(40 + i, cx, cy, r, post_angle=ang))
    put("rig_dark.png", rig(50, level=25))
    put("rig_bright.png", rig(51, level=235))
    put("rig.jpg", rig(52))
    put("gray.png", cv2.cvtColor(rig(53), cv2.COLOR_BGR2GRAY))
    put("bgra.png", cv2.cvtColor(rig(54), cv2.COLOR_BGR2BGRA))
    put("small.png", rig(55, 160, 120, 50, h=240, w=320))
    put("large.png", rig(56, 1000, 500, 330, h=1080, w=1920))
    put("plain.png", sphere_frame(seed=57))
    put("upscaled.png", sphere_frame(h=100, w=120, cx=60, cy=50, r=30, seed=16))
    camfile = d / "lens.json"
    camfile.write_text(json.dumps(LENS))
    r_exp = preprocess.camera_geometry(LENS)[0]
    put("lens.png", through_lens(rig(58, 430.0, 300.0, r_exp * 0.95), LENS), camfile)
    put("lens_centre.png", through_lens(rig(59, 330.0, 250.0, r_exp * 1.1), LENS), camfile)
    return out


def v2_run(run, model, path, cam, tmp_path):
    out = tmp_path / (path.name + ".f32")
    args = ["--model", model, "--dump-tensor", out, path]
    if cam is not None:
        args = ["--camera-file", cam] + args
    return run(*args), out


def test_v2_bit_identical(run, models, v2_frames, tmp_path):
    for path, cam in v2_frames:
        camera = json.loads(cam.read_text()) if cam else None
        r, out = v2_run(run, models["v2"], path, cam, tmp_path)
        assert r.rc == 0, (path.name, r.stdout, r.stderr)
        py = preprocess.preprocess_file(path, V2, camera)
        c = np.fromfile(out, np.float32).reshape(py.shape)
        assert np.array_equal(c, py), (path.name, int((c != py).sum()))
        frame = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        _, (cx, cy, rad) = preprocess.crop_frame(frame, V2, camera)
        line = r.lines[0]
        assert line["circle"] == [round(cx + 0.5, 3), round(cy + 0.5, 3), round(rad, 3)], (path.name, line)


def test_v2_finds_the_true_circle_through_a_lens(run, models, v2_frames, tmp_path):
    path, cam = [f for f in v2_frames if f[0].name == "lens.png"][0]
    r, _ = v2_run(run, models["v2"], path, cam, tmp_path)
    cx, cy, rad = r.lines[0]["circle"]
    r_exp = preprocess.camera_geometry(LENS)[0] * 0.95
    assert math.hypot(cx - 430.5, cy - 300.5) < 0.6 and abs(rad / r_exp - 1) < 0.006, r.lines[0]


def test_v2_errors_on_both_sides(run, models, tmp_path):
    rng = np.random.default_rng(70)
    # two spheres of one texture: the same draws (colours and blobs) for both
    b1, w1 = rc.drawn_sphere(H, W, 170.0, 250.0, 100.0, np.random.default_rng(69))
    b2, w2 = rc.drawn_sphere(H, W, 470.0, 260.0, 105.0, np.random.default_rng(69))
    cases = {
        "flat.png": (np.full((H, W, 3), 90, np.uint8), "no sphere found in frame"),
        "clutter.png": (rc.finish(rc.clutter(rng, H, W), rng), "no sphere found in frame"),
        "two.png": (rc.over(b2, w2, rc.over(b1, w1, rc.clutter(rng, H, W))), "two spheres in frame"),
        "cut.png": (rig(71, W - 1 - 120 * math.cos(math.pi / 4), 250.0, 120.0, post_angle=180),
                    "sphere cut by the frame edge"),
    }
    for name, (img, msg) in cases.items():
        p = tmp_path / name
        cv2.imwrite(str(p), img)
        with pytest.raises(preprocess.NoSphere) as e:
            preprocess.preprocess_file(p, V2)
        assert msg in str(e.value), (name, str(e.value))
        r, _ = v2_run(run, models["v2"], p, None, tmp_path)
        assert r.rc == 1 and msg in r.lines[0]["error"], (name, r.stdout)
        # the same words: "... (circles at ... r ...)" and "(N % of its rim ...)" too
        assert str(e.value).split(": ", 1)[1] in r.lines[0]["error"], (name, str(e.value), r.lines[0])


def test_v2_model_and_camera_file_checks(run, models, tmp_path):
    frame = tmp_path / "f.png"
    cv2.imwrite(str(frame), rig(80))
    # a v2 model whose metadata lacks a key is refused, naming the key
    m = make_model.build("v2")
    for prop in m.metadata_props:
        if prop.key == "spherepose.preprocess":
            pp = json.loads(prop.value)
            del pp["rays"]
            prop.value = json.dumps(pp)
    bad = tmp_path / "norays.onnx"
    import onnx
    onnx.save(m, str(bad))
    r = run("--model", bad, frame)
    assert r.rc == 2 and '"rays"' in r.stderr, r.stderr
    # camera files: unknown key, bad value, other frame size; a v1 model takes none
    cases = [({"focal": 16}, 'unknown key "focal"'), ({"distortion": [0.1, 0]}, '"distortion" must be a list of 5'),
             ({"width": 800, "height": 600}, "frame is 640x512, the camera file's calibration is for 800x600")]
    for cam, msg in cases:
        cf = tmp_path / "cam.json"
        cf.write_text(json.dumps(cam))
        r = run("--camera-file", cf, "--model", models["v2"], frame)
        assert msg in r.stderr + r.stdout, (cam, r.stderr, r.stdout)
    cf.write_text("{}")
    r = run("--camera-file", cf, "--model", models["good"], frame)
    assert r.rc == 2 and "sphere-crop-v1, which takes no camera file" in r.stderr, r.stderr
