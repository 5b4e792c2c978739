"""The evaluation ray-caster (bench/raycast) follows docs/conventions.md on its own.

- rays through each visible test-vector pixel meet the sphere at that point's
  (lat, lon); through an invisible point's pixel they meet another point;
- marks painted on a texture at the vectors' points render at their pixels;
- the outline is a circle of radius f/p * R / sqrt(D^2 - R^2) centred on the
  (shifted) principal point, and the lens model is OpenCV's;
- a family folder gets its frames and truth.jsonl; a seed gives the same
  bytes again.
"""
import json
import math
import os
import sys

import cv2
import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "bench"))

from raycast import camera, families, frames, render  # noqa: E402

VECTORS = os.path.join(ROOT, "tests", "data", "conventions_vectors.json")


@pytest.fixture(scope="module")
def vectors():
    with open(VECTORS, encoding="utf-8") as f:
        return json.load(f)


def flat_scene(pose, **over):
    """A scene lit by the ambient term alone: the frame shows the texture's values."""
    s = {"pose": list(pose), "distance_mm": over.pop("distance_mm", 250.0), "shift_px": [0.0, 0.0],
         "background": {"kind": "uniform", "colour": [0.0, 0.0, 0.0]}, "mount": None, "lights": [],
         "ambient": 1.0, "sheen": {"specular": 0.0, "power": 1.0}, "exposure": 1.0, "vignetting": 0.0,
         "blur": None, "noise": None, "gamma": 1.0, "jpeg": 0, "seed": 0}
    s.update(over)
    return s


def angular_deg(lat1, lon1, lat2, lon2):
    a = np.radians([lat1, lon1])
    b = np.radians([lat2, lon2])
    va = [math.cos(a[0]) * math.sin(a[1]), math.sin(a[0]), math.cos(a[0]) * math.cos(a[1])]
    vb = [math.cos(b[0]) * math.sin(b[1]), math.sin(b[0]), math.cos(b[0]) * math.cos(b[1])]
    return math.degrees(math.acos(min(1.0, max(-1.0, float(np.dot(va, vb))))))


def test_rays_meet_the_vectors_points(vectors):
    cam = camera.camera_from_dict(vectors["camera"])
    for case in vectors["cases"]:
        scene = flat_scene(case["pose_deg"])
        uv = np.array([p["pixel_uv"] for p in case["points"]])
        lat, lon = render.surface_coords(scene, cam, uv[:, 0], uv[:, 1])
        for p, la, lo in zip(case["points"], lat, lon):
            where = f"pose {case['pose_deg']} point ({p['lat_deg']}, {p['lon_deg']})"
            if p["visible"]:
                assert angular_deg(la, lo, p["lat_deg"], p["lon_deg"]) < 0.01, where
            else:   # its pixel shows the sphere's front side (or nothing), never the point itself
                assert np.isnan(la) or angular_deg(la, lo, p["lat_deg"], p["lon_deg"]) > 1.0, where


def mark_texture(points, height=1024, cap_deg=1.5):
    """Black texture with a white cap of `cap_deg` around each (lat, lon)."""
    w = 2 * height
    rows, cols = np.mgrid[0:height, 0:w]
    lat = np.radians(90.0 - (rows + 0.5) * 180.0 / height)
    lon = np.radians((cols + 0.5) * 360.0 / w - 180.0)
    d = np.stack([np.cos(lat) * np.sin(lon), np.sin(lat), np.cos(lat) * np.cos(lon)], axis=-1)
    tex = np.zeros((height, w, 3), np.float32)
    for la, lo in points:
        la, lo = math.radians(la), math.radians(lo)
        c = np.array([math.cos(la) * math.sin(lo), math.sin(la), math.cos(la) * math.cos(lo)])
        tex[d @ c > math.cos(math.radians(cap_deg))] = 1.0
    return tex


@pytest.mark.parametrize("case_index", [0, 5])
def test_marks_render_at_vector_pixels(vectors, case_index):
    cam = camera.camera_from_dict(vectors["camera"])
    case = vectors["cases"][case_index]
    tex = mark_texture([(p["lat_deg"], p["lon_deg"]) for p in case["points"]])
    img = render.render(flat_scene(case["pose_deg"]), cam, tex, supersample=2)
    gray = img[..., 0].astype(np.float64)
    n, labels, stats, cents = cv2.connectedComponentsWithStats((gray > 60).astype(np.uint8))
    # Weighted centroids in continuous pixels (OpenCV's pixel centre c is the conventions' c + 0.5).
    ys, xs = np.mgrid[0:gray.shape[0], 0:gray.shape[1]]
    found = [((xs[labels == k] + 0.5) * gray[labels == k]).sum() / gray[labels == k].sum() for k in range(1, n)]
    found = np.array([[f, ((ys[labels == k] + 0.5) * gray[labels == k]).sum() / gray[labels == k].sum()]
                      for k, f in zip(range(1, n), found)])
    visible = [p for p in case["points"] if p["visible"]]
    for p in visible:
        dist = np.linalg.norm(found - np.array(p["pixel_uv"]), axis=1)
        assert dist.min() < 1.0, f"pose {case['pose_deg']} point ({p['lat_deg']}, {p['lon_deg']}): {dist.min():.2f} px"
    # Marks on the far side do not show (a point just over the limb may still show a sliver of its cap).
    assert len(found) <= len(case["points"])


def test_outline_radius_and_centre():
    cam = camera.Camera(width=320, height=256, focal_mm=8.0)     # a small frame keeps the test fast
    shift = (37.25, -21.5)
    scene = flat_scene((0, 0, 0), distance_mm=230.0, shift_px=list(shift))
    tex = np.ones((64, 128, 3), np.float32)
    img = render.radiance(scene, cam, tex, supersample=8)[..., 0]
    r_expected = cam.f_px * 20.0 / math.sqrt(230.0 ** 2 - 20.0 ** 2)
    r_found = math.sqrt(img.sum() / math.pi)
    assert abs(r_found - r_expected) < 0.02, (r_found, r_expected)
    ys, xs = np.mgrid[0:img.shape[0], 0:img.shape[1]]
    cx = ((xs + 0.5) * img).sum() / img.sum()
    cy = ((ys + 0.5) * img).sum() / img.sum()
    assert abs(cx - (160 + shift[0])) < 0.01 and abs(cy - (128 + shift[1])) < 0.01
    assert render.circle(scene, cam) == pytest.approx((160 + shift[0], 128 + shift[1], r_expected))


def test_lens_model_is_opencvs():
    k = (-0.21, 0.06, 0.0012, -0.0008, 0.01)
    cam = camera.Camera(distortion=k, principal_px=(331.0, 249.5))
    u, v = np.meshgrid(np.linspace(0, 640, 9), np.linspace(0, 512, 7))
    u, v = u.ravel(), v.ravel()
    u0, v0 = cam.principal
    xu, yu = camera.undistort((u - u0) / cam.f_px, (v - v0) / cam.f_px, k)
    # OpenCV's own inverse, in its integer-centred pixels: cx = u0 - 0.5.
    K = np.array([[cam.f_px, 0, u0 - 0.5], [0, cam.f_px, v0 - 0.5], [0, 0, 1]])
    ref = cv2.undistortPointsIter(np.stack([u - 0.5, v - 0.5], 1).reshape(-1, 1, 2), K, np.array(k), None, None,
                                  (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)).reshape(-1, 2)
    assert np.abs(ref[:, 0] - xu).max() * cam.f_px < 1e-4
    assert np.abs(ref[:, 1] - yu).max() * cam.f_px < 1e-4
    xd, yd = camera.distort(xu, yu, k)
    assert np.abs(u0 + cam.f_px * xd - u).max() < 1e-6 and np.abs(v0 + cam.f_px * yd - v).max() < 1e-6


def test_camera_file_errors(tmp_path):
    bad = tmp_path / "cam.json"
    bad.write_text('{"width": 640, "focus_mm": 16}')
    with pytest.raises(camera.CameraFileError, match="cam.json.*focus_mm"):
        camera.load_camera(bad)
    bad.write_text('{"distortion": [0.1, 0.2]}')
    with pytest.raises(camera.CameraFileError, match="distortion"):
        camera.load_camera(bad)


@pytest.fixture(scope="module")
def small_texture(tmp_path_factory):
    rng = np.random.default_rng(5)
    coarse = rng.integers(0, 256, (16, 32, 3), dtype=np.uint8)
    path = tmp_path_factory.mktemp("tex") / "tex.png"
    cv2.imwrite(str(path), cv2.resize(coarse, (512, 256), interpolation=cv2.INTER_NEAREST))
    return str(path)


def test_family_folder_and_truth(tmp_path, small_texture):
    cam = camera.Camera()
    out = tmp_path / "rig"
    frames.write_family(str(out), "rig-unseen", 2, 7, cam, small_texture, supersample=1)
    lines = [json.loads(x) for x in (out / "truth.jsonl").read_text().splitlines()]
    assert len(lines) == 2
    for t in lines:
        assert (out / t["file"]).is_file()
        assert t["file"] == frames.frame_name(t["pose"])
        assert all(-30 <= a <= 30 for a in t["pose"])
        cx, cy, r = t["circle"]
        assert 0 < cx - r and cx + r < 640 and 0 < cy - r and cy + r < 512
        assert t["scene"]["mount"] is not None and t["scene"]["hidden_rim"] <= families.MAX_HIDDEN_RIM
        assert cv2.imread(str(out / t["file"])).shape == (512, 640, 3)


def test_same_seed_same_bytes(small_texture):
    cam = camera.Camera()
    tex = render.load_texture(small_texture)
    a = frames.make_frame("rig", 3, 1, cam, tex, supersample=1)
    b = frames.make_frame("rig", 3, 1, cam, tex, supersample=1)
    c = frames.make_frame("rig", 4, 1, cam, tex, supersample=1)
    assert a[0] == b[0] and a[1] == b[1] and a[2] == b[2]
    assert a[0] != c[0]


def test_names_follow_the_conventions():
    assert frames.frame_name([12.0, -3.0, 30.0]) == "12_-3_30.png"
    assert frames.frame_name([7.5, 3.25, -14.125]) == "7.5_3.25_-14.125.png"
    assert frames.frame_name([-0.0004, 0.1, -29.9999]) == "0_0.1_-30.png"


def test_lens_frame_undistorts_to_the_truth_circle():
    """A frame through a distorting lens, undistorted by OpenCV, shows the sphere on truth's circle."""
    lens = camera.load_camera(os.path.join(ROOT, "bench", "raycast", "cameras", "lens.json"))
    assert lens.distorted
    # The same lens on a small frame (half the size and focal length) keeps the test fast.
    cam = lens.at(width=320, height=256, focal_mm=8.0, principal_px=(163.25, 125.5))
    scene = flat_scene((0, 0, 0), shift_px=[70.0, -45.0])
    tex = np.ones((64, 128, 3), np.float32)
    img = render.radiance(scene, cam, tex, supersample=4)[..., 0]
    u0, v0 = cam.principal
    K = np.array([[cam.f_px, 0, u0 - 0.5], [0, cam.f_px, v0 - 0.5], [0, 0, 1]])
    und = cv2.undistort(img, K, np.array(cam.distortion))
    cx, cy, r = render.circle(scene, cam)
    ys, xs = np.mgrid[0:und.shape[0], 0:und.shape[1]]
    assert abs(math.sqrt(und.sum() / math.pi) - r) < 0.1
    assert abs(((xs + 0.5) * und).sum() / und.sum() - cx) < 0.1
    assert abs(((ys + 0.5) * und).sum() / und.sum() - cy) < 0.1
    # The distorted frame itself is not that circle (the lens moved it).
    assert abs(((xs + 0.5) * img).sum() / img.sum() - cx) > 0.5


def test_edge_and_refuse_families(small_texture):
    cam = camera.Camera()
    for i in range(6):   # the share of the outline beyond the frame is the one drawn
        s = families.draw_scene("edge", 0, i, cam)
        cx, cy, r = render.circle(s, cam)
        a = np.linspace(0, 2 * np.pi, 3600, endpoint=False)
        u, v = cx + r * np.cos(a), cy + r * np.sin(a)
        outside = np.mean((u < 0) | (u > cam.width) | (v < 0) | (v > cam.height))
        assert abs(outside - s["outside"]["share"]) < 0.002 and 0.02 <= outside <= 0.12
    tex = render.load_texture(small_texture)
    kinds = {}
    for i in range(12):
        s = families.draw_scene("refuse", 0, i, cam)
        kinds.setdefault(s["refuse"], i)
    assert set(kinds) == {"none", "two", "cut"}
    _, _, truth = frames.make_frame("refuse", 0, kinds["none"], cam, tex, supersample=1)
    assert truth["expect"] == "refuse" and truth["circle"] is None
    s = families.draw_scene("refuse", 0, kinds["two"], cam)
    c = np.asarray(s["others"][0]["centre_mm"])
    far = camera.project(cam.at(distance_mm=s["distance_mm"]), [c], shift=s["shift_px"])[0]
    hit, _, _, _ = render.trace(s, cam, [far[0], *render.circle(s, cam)[:1]], [far[1], render.circle(s, cam)[1]])
    assert list(hit) == [render.OTHERS, render.SPHERE]     # both spheres in the frame, each where it projects


def test_family_folder_reuse_and_foreign_frames(tmp_path, small_texture):
    """A folder made before is reused when the same texture is reached by another path; a new
    set replaces only the tool's own frames; PNG files in a folder it did not make are kept."""
    cam = camera.Camera()
    out = tmp_path / "fam"
    frames.write_family(str(out), "clean", 1, 3, cam, small_texture, supersample=1)
    made = {p.name: p.stat().st_mtime_ns for p in out.glob("*.png")}
    link = tmp_path / "elsewhere.png"
    link.symlink_to(small_texture)
    frames.write_family(str(out), "clean", 1, 3, cam, str(link), supersample=1)
    assert {p.name: p.stat().st_mtime_ns for p in out.glob("*.png")} == made   # reused, not rendered
    frames.write_family(str(out), "clean", 1, 4, cam, small_texture, supersample=1)  # another seed
    assert len(list(out.glob("*.png"))) == 1 and set(p.name for p in out.glob("*.png")) != set(made)

    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "photo.png").write_bytes(b"not ours")
    with pytest.raises(frames.FolderError, match="no params.json"):
        frames.write_family(str(theirs), "clean", 1, 3, cam, small_texture, supersample=1)
    assert (theirs / "photo.png").read_bytes() == b"not ours"
