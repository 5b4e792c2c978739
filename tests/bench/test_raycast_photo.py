"""The ray-caster's `rig-photo` family (bench/raycast/families.py): the rig's scene in front of a real
photograph bundled with scikit-image or matplotlib. The family draws and draws again identically from
(seed, index), its backdrop is the named photo and every listed photo loads offline (that every
family keeps its seed stream: test_raycast_streams.py)."""
import math
import os
import sys

import cv2
import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "bench"))

from raycast import backgrounds, camera, families, frames, render  # noqa: E402

# A small frame keeps the test fast: a quarter of the reference frame with 4x the pixel pitch
# (sphere radius about 33 px instead of 134).
SMALL = camera.Camera(width=160, height=128, pixel_mm=0.0384)


def test_every_listed_photo_loads_offline():
    for name in backgrounds.PHOTOS:
        assert os.path.isfile(backgrounds.photo_path(name)), name
        img = backgrounds.load_photo(name)
        assert img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.float32, name
        assert min(img.shape[:2]) >= 256 and 0.0 <= img.min() and img.max() <= 1.0, name
    with pytest.raises(ValueError, match="unknown photo"):
        backgrounds.photo_path("chessboard")


def test_scenes_draw_again_and_stay_in_their_ranges():
    cam = camera.Camera()
    photos, mounts = set(), set()
    for i in range(40):
        s = families.draw_scene("rig-photo", 5, i, cam)
        assert s == families.draw_scene("rig-photo", 5, i, cam)
        bg = s["background"]
        assert bg["kind"] == "photo" and bg["photo"] in backgrounds.PHOTOS
        assert backgrounds.PHOTO_ZOOM[0] <= bg["zoom"] <= backgrounds.PHOTO_ZOOM[1]
        assert backgrounds.PHOTO_GAIN[0] <= bg["gain"] <= backgrounds.PHOTO_GAIN[1]
        assert backgrounds.PHOTO_BLUR_PX[0] <= bg["blur_px"] <= backgrounds.PHOTO_BLUR_PX[1]
        assert all(0.0 <= c <= 1.0 for c in bg["crop"]) and isinstance(bg["flip"], bool)
        assert render.hidden_rim_fraction(s, cam) <= families.MAX_HIDDEN_RIM + 1e-9
        photos.add(bg["photo"])
        mounts.add((s["mount"]["type"], s["mount"].get("shape")))
    assert len(photos) >= 10 and ("post", "cylinder") in mounts and len(mounts) >= 3
    assert families.draw_scene("rig-photo", 6, 0, cam) != families.draw_scene("rig-photo", 5, 0, cam)


def _photo_window(p, width, height):
    """The backdrop the record describes, made here another way: the photo read by OpenCV's PNG/JPEG
    reader as grey or colour, each frame pixel centre mapped back into the photo and sampled bilinearly
    (no defocus, no gain)."""
    img = cv2.imread(backgrounds.photo_path(p["photo"]), cv2.IMREAD_UNCHANGED)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    img = cv2.cvtColor(img[..., :3], cv2.COLOR_BGR2RGB).astype(np.float32) / 255.0
    if p["flip"]:
        img = np.ascontiguousarray(img[:, ::-1])
    ph, pw = img.shape[:2]
    scale = max(width / pw, height / ph) * p["zoom"]
    x0 = round(p["crop"][0] * (max(width, math.ceil(pw * scale)) - width))
    y0 = round(p["crop"][1] * (max(height, math.ceil(ph * scale)) - height))
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float32)
    mx = (xs + x0 + 0.5) / scale - 0.5
    my = (ys + y0 + 0.5) / scale - 0.5
    return cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def _corr(a, b):
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / math.sqrt((a * a).sum() * (b * b).sum()))


def test_frame_backdrop_is_the_named_photo():
    cam = SMALL
    tex = np.full((64, 128, 3), 0.5, np.float32)
    for i in range(2):
        name, png, truth = frames.make_frame("rig-photo", 9, i, cam, tex, supersample=1)
        assert frames.make_frame("rig-photo", 9, i, cam, tex, supersample=1) == (name, png, truth)
        s = truth["scene"]
        assert s["background"]["kind"] == "photo" and truth["circle"] is not None
        img = cv2.cvtColor(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
        ys, xs = np.mgrid[0:cam.height, 0:cam.width]
        hit = render.trace(s, cam, xs + 0.5, ys + 0.5)[0].reshape(cam.height, cam.width)
        # backdrop pixels away from the sphere and the mount (blur and anti-aliasing reach a few px)
        free = cv2.erode((hit == render.BACKDROP).astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
        assert free.mean() > 0.3
        grey = img.astype(np.float32).mean(axis=2)[free]
        mine = _photo_window(s["background"], cam.width, cam.height).mean(axis=2)[free]
        assert _corr(grey, mine) > 0.8, (i, s["background"])
        mirrored = dict(s["background"], flip=not s["background"]["flip"])
        assert _corr(grey, _photo_window(mirrored, cam.width, cam.height).mean(axis=2)[free]) < 0.75
        others = [n for n in sorted(backgrounds.PHOTOS) if n != s["background"]["photo"]][:3]
        for other in others:   # the same window of another photo does not match
            p = dict(s["background"], photo=other)
            assert abs(_corr(grey, _photo_window(p, cam.width, cam.height).mean(axis=2)[free])) < 0.6, other
