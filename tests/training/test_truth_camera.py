"""A rig scene's truth.jsonl camera and the camera file are one camera: sim/camera.from_truth turns
what sim/scene.draw records for a frame into camera-file keys, the one conversion that training
(load_crops) and python -m training.refine both use (training/data.frame_camera)."""
import json
import os

import numpy as np
import pytest

from sim.camera import REFERENCE, camera_from_dict, from_truth
from sim.scene import draw, load_scene
from training import data
from training.preprocess import camera_geometry

SCENES = os.path.join(os.path.dirname(__file__), "..", "..", "sim", "scenes")


@pytest.mark.parametrize("name", ["rig.json", "train.json"])
def test_drawn_camera_round_trips(name):
    scene = load_scene(os.path.join(SCENES, name))
    for i in range(20):
        prm = draw(scene, np.random.default_rng([7, i]))
        drawn = prm["camera"]
        keys = dict(from_truth(drawn), width=drawn["width"], height=drawn["height"])
        r_px, f, cx, cy, dist = camera_geometry(keys)
        # the circle the truth line gives, from the camera-file keys alone
        assert r_px == pytest.approx(prm["circle"][2], rel=1e-12)
        assert f == pytest.approx(drawn["focal_px"], rel=1e-12)
        assert (cx + 0.5, cy + 0.5) == pytest.approx(tuple(drawn["principal_px"]), abs=1e-12)
        assert (dist or [0.0] * 5) == pytest.approx(drawn["distortion"])
        # and they are a valid camera file
        cam = camera_from_dict({k: v for k, v in keys.items() if v is not None}, "truth")
        assert cam.focal_px == pytest.approx(drawn["focal_px"], rel=1e-12)
        assert cam.radius_px * drawn["distance_mm"] > 0


def test_older_records_take_the_reference():
    keys = from_truth({"focal_px": 1600.0})
    assert keys["pixel_mm"] == REFERENCE["pixel_mm"] and keys["distance_mm"] == REFERENCE["distance_mm"]
    assert keys["sphere_diameter_mm"] == REFERENCE["sphere_diameter_mm"]
    assert keys["principal_px"] is None and keys["distortion"] is None


def test_frame_camera_per_folder(tmp_path, monkeypatch):
    rig, plain = tmp_path / "rig", tmp_path / "plain"
    rig.mkdir()
    plain.mkdir()
    rec = {"file": "1_2_3.png", "pose": [1, 2, 3], "circle": [80, 64, 40],
           "scene": {"camera": {"focal_px": 1700.0, "principal_px": [81.0, 63.0],
                                "distortion": [-0.1, 0.02, 0, 0, 0], "distance_mm": 240.0}}}
    (rig / "truth.jsonl").write_text(json.dumps(rec) + "\n")
    reads = []
    real = data.frame_cameras
    monkeypatch.setattr(data, "frame_cameras", lambda root: reads.append(root) or real(root))
    frame, default = np.zeros((128, 160, 3), np.uint8), {"focal_mm": 12.0}
    folders = {}
    cam = data.frame_camera(folders, rig / "1_2_3.png", frame, default)
    assert cam == dict(from_truth(rec["scene"]["camera"]), width=160, height=128)
    assert data.frame_camera(folders, rig / "4_5_6.png", frame, default) is default
    assert data.frame_camera(folders, plain / "1_2_3.png", frame, default) is default
    assert data.frame_camera(folders, plain / "1_2_3.png", frame) is None
    assert reads == [rig, plain]    # each folder's truth.jsonl read once
