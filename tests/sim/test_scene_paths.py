"""A rig scene is portable: its camera file and photos folder are found relative to the scene file
(not the working directory), so a scene folder copied to another place (a clone elsewhere, a
cluster's shared filesystem) renders the same frames; absolute paths keep working; the dataset
record names no path of this machine (docs/sim.md, "background.photos")."""
import json
import os
import shutil

import cv2
import numpy as np

from sim.scene import load_scene
from sim.scene_render import SceneRenderer

SMALL_CAMERA = {"width": 160, "height": 128, "pixel_mm": 0.0384}


def make_scene_folder(root, photos_ref="lab"):
    root.mkdir()
    (root / "cam.json").write_text(json.dumps(SMALL_CAMERA))
    lab = root / "lab"
    lab.mkdir()
    rng = np.random.default_rng(0)
    for i in range(2):
        img = np.kron(rng.integers(0, 255, (12, 16, 3)), np.ones((20, 20, 1))).astype(np.uint8)
        cv2.imwrite(str(lab / f"p{i}.png"), img)
    scene = {"camera": "cam.json", "mount": {"kind": {"none": 1}},
             "background": {"kind": {"photo": 1}, "photos": photos_ref}}
    (root / "scene.json").write_text(json.dumps(scene))
    return root / "scene.json"


def frames(scene, texture, n=2):
    sr = SceneRenderer(texture, scene)
    return [sr.frame((3, -4, 5), np.random.default_rng([11, i]))[0] for i in range(n)]


def test_relative_paths_follow_the_scene_file(tmp_path, monkeypatch, stripe_rgb):
    path = make_scene_folder(tmp_path / "here")
    elsewhere = tmp_path / "cwd"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)            # the working directory plays no part
    here = load_scene(os.path.relpath(path))
    assert here.camera.width == 160
    assert [os.path.dirname(p) for p in here.photos] == [str(tmp_path / "here" / "lab")] * 2
    before, record = frames(here, stripe_rgb), here.settings()

    moved = tmp_path / "there"
    shutil.move(str(tmp_path / "here"), str(moved))
    there = load_scene(str(moved / "scene.json"))
    assert [os.path.dirname(p) for p in there.photos] == [str(moved / "lab")] * 2
    after = frames(there, stripe_rgb)
    assert all(np.array_equal(a, b) for a, b in zip(before, after))
    # the record a dataset keeps (dataset.json "scene") is the same wherever the folder is, and
    # names no folder of this machine
    assert there.settings() == record
    assert str(tmp_path) not in json.dumps(there.settings())


def test_absolute_photos_folder(tmp_path, stripe_rgb):
    rel = load_scene(str(make_scene_folder(tmp_path / "a")))
    absolute = load_scene(str(make_scene_folder(tmp_path / "b", photos_ref=str(tmp_path / "a" / "lab"))))
    assert [os.path.dirname(p) for p in absolute.photos] == [str(tmp_path / "a" / "lab")] * 2
    assert all(np.array_equal(x, y) for x, y in zip(frames(rel, stripe_rgb), frames(absolute, stripe_rgb)))
