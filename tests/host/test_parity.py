"""Preprocessing parity: the C++ shim (through `poseinfer --dump-tensor`) and
training/preprocess.py give the same network input on the same frames
(within 1e-3), and the same angles through the same model (within 0.01 deg).
Frames: centred, off-centre, partly out of frame, small, large, gray,
upscaled crop, a JPEG, and a rendered frame when the renderer is there."""
import json
import subprocess

import numpy as np
import pytest

from pihelpers import ROOT, sphere_frame
from training import preprocess

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
        tex = d / "tex.png"
        rng = np.random.default_rng(3)
        t = np.full((256, 512, 3), 230, np.uint8)
        for _ in range(60):
            cv2.circle(t, (int(rng.integers(0, 512)), int(rng.integers(0, 256))), int(rng.integers(5, 30)),
                       tuple(int(v) for v in rng.integers(0, 255, 3)), -1)
        cv2.imwrite(str(tex), t)
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
        py = preprocess.preprocess_file(p)
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
        cx, cy, rad, _ = preprocess.find_sphere(cv2.imread(str(p), cv2.IMREAD_UNCHANGED))
        assert abs(line["cx"] - cx) < 0.01 and abs(line["cy"] - cy) < 0.01 and abs(line["r"] - rad) < 0.01
        worst_t, worst_a = max(worst_t, dt), max(worst_a, da)
    print(f"parity over {len(parity_frames)} frames: tensor max |diff| {worst_t:.3g}, angles {worst_a:.3g} deg")


def test_no_sphere_on_both_sides(run, models, tmp_path):
    p = tmp_path / "flat.png"
    cv2.imwrite(str(p), np.full((200, 300, 3), 90, np.uint8))
    with pytest.raises(preprocess.NoSphere):
        preprocess.preprocess_file(p)
    r = run("--model", models["good"], "--dump-tensor", tmp_path / "x.f32", p)
    assert r.rc == 1 and "no sphere found in frame" in r.lines[0]["error"]
