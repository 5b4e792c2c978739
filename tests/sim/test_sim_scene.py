"""Rig scenes: scene files, per-frame draw, truth circles, lens distortion, `--scene` on the commands."""
import hashlib
import json
import os
import subprocess
import sys

import cv2
import numpy as np
import pytest

from sim.camera import CameraError, camera_from_dict
from sim.dataset import SPLITS, TRUTH, DatasetConfig, build
from sim.scene import SceneError, draw, load_scene, scene_from_dict
from sim.scene_render import SceneRenderer

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SCENES = os.path.join(REPO, "sim", "scenes")
SMALL_CAMERA = {"width": 160, "height": 128, "pixel_mm": 0.0384}
MAGENTA = [255, 0, 255]


def run_sim(*args):
    return subprocess.run([sys.executable, "-m", "sim.cli", *args], capture_output=True, text=True)


def write_scene(tmp_path, obj, name="scene.json"):
    p = tmp_path / name
    p.write_text(json.dumps(obj))
    return str(p)


def silhouette_circle(frame_rgb, background_rgb, threshold=100):
    """(cx, cy, r) in continuous pixels of the pixels far from the background colour (area and centroid)."""
    diff = np.abs(frame_rgb.astype(int) - np.asarray(background_rgb)).max(axis=2)
    ys, xs = np.nonzero(diff > threshold)
    return xs.mean() + 0.5, ys.mean() + 0.5, np.sqrt(len(xs) / np.pi)


# A scene whose sphere stands out from a flat magenta background with every effect off.
CLEAN = {"camera": {}, "view": {"distance_scale": [0.92, 1.08], "focal_scale": [0.96, 1.04],
                                "offset_u_px": [-100, 100], "offset_v_px": [-80, 80]},
         "lights": [{"direction": [0, 0, 1], "intensity": 0.6}],
         "background": {"kind": {"flat": 1}, "color": MAGENTA}}


# ---- scene files -----------------------------------------------------------------

def test_shipped_scenes_parse():
    for name in ("train.json", "rig.json"):
        scene = load_scene(os.path.join(SCENES, name))
        params = draw(scene, np.random.default_rng(0))
        json.dumps(params)  # the draw is JSON, as truth.jsonl writes it
    rig = load_scene(os.path.join(SCENES, "rig.json"))
    assert rig.camera.distorted and rig.camera.principal == (324.5, 251.0)


@pytest.mark.parametrize("obj,words", [
    ({"mounts": {}}, ["unknown key 'mounts'"]),
    ({"mount": {"radius": 3}}, ["unknown key 'mount.radius'"]),
    ({"mount": {"post_radius_mm": [5, 2]}}, ["'mount.post_radius_mm'", "low 5.0 is above high 2.0"]),
    ({"mount": {"kind": {"tripod": 1}}}, ["'mount.kind'", "unknown kind 'tripod'"]),
    ({"mount": {"color": [300, 0, 0]}}, ["'mount.color'"]),
    ({"mount": {"color": {"hue": 10, "sat": 1}}}, ["unknown key 'mount.color.sat'"]),
    ({"view": {"distance_scale": "far"}}, ["'view.distance_scale'", "number or [low, high]"]),
    ({"view": {"focal_scale": 2.0, "distance_scale": 0.9}}, ["'view.focal_scale'", "does not fit"]),
    ({"lights": {"count": [1.5, 2]}}, ["'lights.count'", "whole numbers"]),
    ({"lights": [{"direction": [0, 0, 0]}]}, ["'lights'", "light 0"]),
    ({"background": {"kind": {"photo": 1}}}, ["'background.kind'", "needs a 'photos' folder"]),
    ({"background": {"photos": "no_such_folder"}}, ["'background.photos'", "not found"]),
    ({"image": {"jpeg_quality": [1, 90]}}, ["'image.jpeg_quality'"]),
    ({"image": {"vignetting": 2}}, ["'image.vignetting'", "within"]),
    ({"camera": {"distortion": [0.1, 0]}}, ["'camera'", "'distortion'", "5 finite numbers"]),
    ({"camera": {"focal": 16}}, ["'camera'", "unknown key 'focal'"]),
    ({"distortion": {"k1": [-5, 0]}}, ["'distortion.k1'"]),
    ({"camera": {"focal_mm": 4}, "distortion": {"k1": -1.0}}, ["'distortion'", "fold"]),
    ({"format": "spherepose-scene-9"}, ["'format'"]),
    ([1, 2], ["expected a JSON object"]),
    ({"sphere": {"specular": float("nan")}}, ["'sphere.specular'"]),
])
def test_scene_errors_name_file_and_key(tmp_path, obj, words):
    path = write_scene(tmp_path, obj)
    with pytest.raises(SceneError) as e:
        load_scene(path)
    msg = str(e.value)
    assert path in msg
    for w in words:
        assert w in msg, msg


def test_scene_file_errors_from_the_command(tmp_path, texture_png):
    bad = tmp_path / "bad.json"
    bad.write_text('{"mount": {"kind": {"post": 1}, "tilt_deg": [0, 80]}}')
    r = run_sim("dataset", "--texture", texture_png, "--scene", str(bad), "--out", str(tmp_path / "d"))
    assert r.returncode == 2 and str(bad) in r.stderr and "'mount.tilt_deg'" in r.stderr
    assert not (tmp_path / "d").exists()
    broken = tmp_path / "broken.json"
    broken.write_text('{"mount": ')
    r = run_sim("render", "--texture", texture_png, "--scene", str(broken), "--pose", "0", "0", "0",
                "--out", str(tmp_path / "f.png"))
    assert r.returncode == 2 and str(broken) in r.stderr and "not valid JSON" in r.stderr
    r = run_sim("dataset", "--texture", texture_png, "--scene", os.path.join(SCENES, "rig.json"),
                "--background", "1,2,3", "--noise", "3", "--out", str(tmp_path / "d"))
    assert r.returncode == 2 and "--background" in r.stderr and "--noise" in r.stderr
    assert not (tmp_path / "d").exists() and not (tmp_path / "f.png").exists()


def test_camera_file_calibration_keys(tmp_path):
    cam = camera_from_dict({"principal_px": [300.5, 260], "distortion": [-0.1, 0.02, 0, 0, 0]})
    assert cam.principal == (300.5, 260.0) and cam.distorted
    assert np.allclose(cam.opencv_matrix()[:2, 2], [300.0, 259.5])
    assert cam.to_dict()["distortion"] == [-0.1, 0.02, 0.0, 0.0, 0.0]
    plain = camera_from_dict({})
    assert "distortion" not in plain.to_dict() and "principal_px" not in plain.to_dict()  # old records match
    for values, words in [({"principal_px": [1, "a"]}, "'principal_px'"), ({"distortion": 0.1}, "'distortion'"),
                          ({"distortion": [-5, 0, 0, 0, 0]}, "fold"), ({"distortion": [0, 0, 0.3, 0, 0]}, "tangential")]:
        with pytest.raises(CameraError, match=words):
            camera_from_dict(values, source="cam.json")


# ---- frames -----------------------------------------------------------------------------

@pytest.fixture(scope="module")
def clean_renderer(stripe_rgb):
    return SceneRenderer(stripe_rgb, scene_from_dict(CLEAN))


def test_truth_circle_matches_the_silhouette(clean_renderer):
    for i in range(4):
        img, params = clean_renderer.frame((5.0 * i, -7.0, 11.0), np.random.default_rng([3, i]))
        cx, cy, r = silhouette_circle(img, MAGENTA)
        tx, ty, tr = params["circle"]
        assert abs(cx - tx) < 0.5 and abs(cy - ty) < 0.5 and abs(r - tr) < 0.5, (params["circle"], (cx, cy, r))


def test_distortion_round_trip(stripe_rgb):
    # A wide lens (6 mm) and the sphere far from the principal point, where the distortion moves it most.
    scene = scene_from_dict(dict(CLEAN, camera={"focal_mm": 6.0},
                                 view=dict(CLEAN["view"], offset_u_px=[150, 200], offset_v_px=[-150, 150]),
                                 distortion={"k1": [-0.3, -0.2], "k2": 0.1, "p1": 0.001, "p2": -0.001}))
    sr = SceneRenderer(stripe_rgb, scene)
    for i in range(3):
        img, params = sr.frame((0.0, 10.0, -20.0), np.random.default_rng([5, i]))
        c = params["camera"]
        f, (u0, v0) = c["focal_px"], c["principal_px"]
        K = np.array([[f, 0, u0 - 0.5], [0, f, v0 - 0.5], [0, 0, 1]])
        und = cv2.undistort(img, K, np.array(c["distortion"]))
        tx, ty, tr = params["circle"]
        cx, cy, r = silhouette_circle(und, MAGENTA)
        assert abs(cx - tx) < 0.5 and abs(cy - ty) < 0.5 and abs(r - tr) < 0.5, (params["circle"], (cx, cy, r))
        # ... and the distortion was really applied: the raw frame's outline is elsewhere.
        dx, dy, dr = silhouette_circle(img, MAGENTA)
        assert max(abs(dx - tx), abs(dy - ty), abs(dr - tr)) > 2.0


def test_same_seed_same_frame_and_every_kind_renders(stripe_rgb):
    scene = load_scene(os.path.join(SCENES, "train.json"))
    sr = SceneRenderer(stripe_rgb, scene)
    # The first seeds that draw each mount kind and each background kind (drawing alone is cheap).
    seeds = {}
    for i in range(200):
        p = draw(scene, np.random.default_rng([9, i]))
        seeds.setdefault(p["mount"]["kind"], i)
        seeds.setdefault(p["background"]["kind"], i)
    assert set(seeds) == {"none", "post", "cup", "fork", "flat", "gradient", "clutter"}
    frames = {}
    for i in sorted(set(seeds.values())):
        img, params = sr.frame((1.0, 2.0, 3.0), np.random.default_rng([9, i]))
        assert params == draw(scene, np.random.default_rng([9, i]))
        frames[i] = img
    i0 = min(frames)
    again, _ = sr.frame((1.0, 2.0, 3.0), np.random.default_rng([9, i0]))  # after other frames: same bytes
    assert np.array_equal(frames[i0], again)
    assert len({f.tobytes() for f in frames.values()}) == len(frames)


# ---- datasets ---------------------------------------------------------------------------

def digest(folder):
    out = {}
    for split in SPLITS:
        d = os.path.join(folder, split)
        for name in sorted(os.listdir(d)) if os.path.isdir(d) else []:
            with open(os.path.join(d, name), "rb") as f:
                out[f"{split}/{name}"] = hashlib.sha256(f.read()).hexdigest()
    return out


def small_cfg(texture, scene):
    return DatasetConfig(texture=texture, camera=scene.camera, scene=scene, seed=4,
                         counts={"train": 8, "val": 3, "test": 2, "test_offgrid": 2})


def test_scene_dataset_same_bytes_resume_and_truth(tmp_path, texture_png):
    obj = json.load(open(os.path.join(SCENES, "train.json")))
    obj["camera"] = SMALL_CAMERA
    obj["view"]["offset_u_px"], obj["view"]["offset_v_px"] = [-30, 30], [-20, 20]
    scene = scene_from_dict(obj, str(tmp_path / "small.json"))
    a, b = tmp_path / "a", tmp_path / "b"
    rec = build(small_cfg(texture_png, scene), str(a), workers=2, progress=False, log=lambda *x: None)
    assert rec["complete"] and rec["settings"]["scene"]["file"]["mount"]["kind"]["post"] == 0.55
    build(small_cfg(texture_png, scene), str(b), workers=1, progress=False, log=lambda *x: None)
    da = digest(a)
    assert da == digest(b) and len(da) == 15 + 4  # frames and one truth.jsonl per split
    lines = [json.loads(l) for l in open(a / "train" / TRUTH)]
    assert sorted(l["file"] for l in lines) == sorted(n for n in os.listdir(a / "train") if n.endswith(".png"))
    for l in lines:
        assert len(l["circle"]) == 3 and len(l["pose"]) == 3 and "mount" in l["scene"]
    # Resume: frames and truth lost from a run are made again, identical.
    for name in sorted(n for n in os.listdir(b / "train") if n.endswith(".png"))[:3] + [TRUTH]:
        os.unlink(b / "train" / name)
    os.unlink(b / "val" / TRUTH)
    rec = build(small_cfg(texture_png, scene), str(b), workers=2, progress=False, log=lambda *x: None)
    assert rec["last_run"]["rendered"] == 3 and digest(b) == da
    # Another scene is refused, with the difference named.
    obj["mount"]["post_radius_mm"] = [2, 8]
    other = scene_from_dict(obj, str(tmp_path / "small.json"))
    with pytest.raises(ValueError, match="post_radius_mm"):
        build(small_cfg(texture_png, other), str(b), workers=1, progress=False, log=lambda *x: None)


def test_plain_dataset_truth_is_the_camera_circle(tmp_path, texture_png, small_camera_json):
    r = subprocess.run([sys.executable, "-m", "sim.cli", "dataset", "--texture", texture_png, "--camera",
                        small_camera_json, "--out", str(tmp_path / "d"), "--train", "4", "--val", "0", "--test", "0",
                        "--offgrid-test", "0", "--offset", "10", "--quiet"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    for line in open(tmp_path / "d" / "train" / TRUTH):
        t = json.loads(line)
        img = cv2.cvtColor(cv2.imread(str(tmp_path / "d" / "train" / t["file"])), cv2.COLOR_BGR2RGB)
        cx, cy, rad = silhouette_circle(img, (64, 64, 70), threshold=20)
        assert abs(cx - t["circle"][0]) < 0.5 and abs(cy - t["circle"][1]) < 0.5 and abs(rad - t["circle"][2]) < 0.5


def test_sim_render_scene_writes_frame_and_truth(tmp_path, texture_png):
    out, truth = tmp_path / "f.png", tmp_path / "f.json"
    r = run_sim("render", "--texture", texture_png, "--scene", os.path.join(SCENES, "rig.json"),
                "--pose", "3", "4", "5", "--out", str(out), "--truth", str(truth))
    assert r.returncode == 0, r.stderr
    img = cv2.imread(str(out))
    t = json.loads(truth.read_text())
    assert img.shape == (512, 640, 3) and t["pose"] == [3, 4, 5] and t["scene"]["mount"]["kind"] == "post"


def test_photo_backgrounds(tmp_path, stripe_rgb):
    photos = tmp_path / "lab"
    photos.mkdir()
    rng = np.random.default_rng(0)
    for i in range(2):  # two "photos": noise blocks in a colour each
        img = np.kron(rng.integers(0, 255, (12, 16, 3)), np.ones((20, 20, 1))).astype(np.uint8)
        img[..., i] = 255
        cv2.imwrite(str(photos / f"p{i}.jpg"), img)
    (photos / "notes.txt").write_text("not a photo")
    scene = scene_from_dict({"camera": SMALL_CAMERA, "mount": {"kind": {"post": 1}},
                             "background": {"kind": {"photo": 1}, "photos": "lab", "photo_gain": [0.5, 1.5]}},
                            str(tmp_path / "scene.json"))
    assert [os.path.basename(p) for p in scene.photos] == ["p0.jpg", "p1.jpg"]
    assert [n for n, _ in scene.settings()["photos"]] == ["p0.jpg", "p1.jpg"]
    sr = SceneRenderer(stripe_rgb, scene)
    used = set()
    for i in range(6):
        img, params = sr.frame((0, 0, 0), np.random.default_rng([1, i]))
        used.add(params["background"]["photo"])
        corner = img[:20].reshape(-1, 3).astype(float)
        assert corner.std(axis=0).max() > 10  # the photo's blocks, not a flat colour
    assert used == {"p0.jpg", "p1.jpg"}


def test_broken_photo_is_named_before_rendering(tmp_path):
    (tmp_path / "lab").mkdir()
    (tmp_path / "lab" / "a.png").write_bytes(b"\x89PNG\r\n\x1a\n not really")
    path = write_scene(tmp_path, {"background": {"kind": {"photo": 1}, "photos": "lab"}})
    with pytest.raises(SceneError, match="a.png: not a readable image") as e:
        load_scene(path)
    assert path in str(e.value) and "'background.photos'" in str(e.value)


def test_vcam_serves_scene_frames(tmp_path, texture_png):
    import tempfile
    d = tempfile.mkdtemp(prefix="vs", dir="/tmp")
    vsock = os.path.join(d, "cam")
    scene = write_scene(tmp_path, dict(json.load(open(os.path.join(SCENES, "rig.json"))), camera=SMALL_CAMERA,
                                       view={}))
    proc = subprocess.Popen([sys.executable, "-m", "sim.cli", "vcam", "--texture", texture_png, "--scene", scene,
                             "--pose", "5", "6", "7", "--socket", vsock, "--seed", "3"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().startswith("VCAM "), proc.stderr.read()
        import socket
        frames = []
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as c:
            c.settimeout(30)
            c.connect(vsock)
            f = c.makefile("rb")
            for _ in range(2):
                c.sendall(b"grab\n")
                kind, n = f.readline().split()
                assert kind == b"FRAME"
                frames.append(cv2.imdecode(np.frombuffer(f.read(int(n)), np.uint8), cv2.IMREAD_COLOR))
    finally:
        proc.send_signal(15)
        rc = proc.wait(timeout=20)
        os.rmdir(d)
    assert rc == 0
    # Frame n is the scene's draw from default_rng([seed, n]): the same as rendering it here.
    sr = SceneRenderer(texture_png, load_scene(scene))
    for n, got in enumerate(frames):
        want, _ = sr.frame((5.0, 6.0, 7.0), np.random.default_rng([3, n]))
        np.testing.assert_array_equal(got[:, :, ::-1], want)
    assert not np.array_equal(frames[0], frames[1])  # the sensor noise differs


@pytest.mark.parametrize("direction,kind", [(0, "post"), (90, "post"), (-90, "cup"), (0, "fork")])
def test_mount_touches_the_sphere_from_its_direction(stripe_rgb, direction, kind):
    """Just outside the outline, on the mount's side, is the mount; on the opposite side the background."""
    scene = scene_from_dict(dict(CLEAN, view={}, mount={"kind": {kind: 1}, "direction_deg": direction,
                                                        "post_radius_mm": 6, "color": [0, 255, 0]}))
    img, params = SceneRenderer(stripe_rgb, scene).frame((0, 0, 0), np.random.default_rng(0))
    cx, cy, r = params["circle"]
    a = np.radians(direction)
    side = np.array([np.sin(a), np.cos(a)])  # image (u, v) direction toward the mount (v down)

    def at(dist):
        u, v = np.array([cx, cy]) + dist * side
        return img[int(v), int(u)].astype(int)

    if kind == "fork":  # the prongs meet the sphere beside the axis; the stem starts past the bar
        assert np.abs(at(r + 40) - MAGENTA).max() > 100  # the bar, 6 mm below the sphere
    else:
        for d in (r + 1.5, r + 5, r + 40):
            px = at(d)
            assert px[1] > px[0] + 40 and px[1] > px[2] + 40, (d, px)  # green: the mount
    far = np.array([cx, cy]) - (r + 3) * side
    assert np.abs(img[int(far[1]), int(far[0])].astype(int) - MAGENTA).max() < 10  # background opposite


def test_cli_scene_input_errors(tmp_path, texture_png):
    r = run_sim("render", "--texture", texture_png, "--scene", str(tmp_path / "none.json"), "--pose", "0", "0", "0",
                "--out", str(tmp_path / "f.png"))
    assert r.returncode == 2 and "none.json" in r.stderr and "cannot read scene file" in r.stderr
    r = run_sim("render", "--texture", texture_png, "--pose", "0", "0", "0", "--out", str(tmp_path / "f.png"),
                "--truth", str(tmp_path / "t.json"))
    assert r.returncode == 2 and "--truth needs --scene" in r.stderr
    assert not (tmp_path / "f.png").exists() and not (tmp_path / "t.json").exists()


def test_plain_renderer_follows_the_camera_calibration(stripe_rgb):
    """`sim render --camera` with principal_px and distortion: undistorted, the outline is the camera's circle."""
    from sim.render import Renderer
    cam = camera_from_dict({"focal_mm": 6.0, "principal_px": [420.5, 200.25],
                            "distortion": [-0.25, 0.08, 0.001, -0.0005, 0.0]})
    r = Renderer(stripe_rgb, cam, background=MAGENTA)
    assert r.margin > 0
    img = r.render((10, 20, 30))
    und = cv2.undistort(img, cam.opencv_matrix(), np.array(cam.distortion))
    cx, cy, rad = silhouette_circle(und, MAGENTA)
    assert abs(cx - 420.5) < 0.5 and abs(cy - 200.25) < 0.5 and abs(rad - cam.radius_px) < 0.5, (cx, cy, rad)
