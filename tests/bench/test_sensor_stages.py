"""bench/sensor_stages.py on one small frame: a folder per variant with the frame and the family's
truth line, `all` byte for byte the family's frame, and bench/raycast's folder rules (a complete
folder reused, someone else's PNG files or another camera's camera.json left alone)."""
import json
import os
import sys

import cv2
import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "bench"))

import sensor_stages  # noqa: E402
from raycast import camera, frames, render  # noqa: E402

# A quarter of the reference frame with 4x the pixel pitch (sphere radius about 33 px): fast.
SMALL = camera.Camera(width=160, height=128, pixel_mm=0.0384)


@pytest.fixture()
def setup(tmp_path):
    tex = tmp_path / "tex.png"
    cv2.imwrite(str(tex), np.random.default_rng(2).integers(0, 256, (64, 128, 3), dtype=np.uint8))
    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps(SMALL.to_dict()))
    return tmp_path, ["--seed", "601", "--n", "1", "--texture", str(tex), "--camera", str(cam),
                      "--supersample", "1"]


def test_one_frame_in_every_variant(setup):
    tmp, args = setup
    out = tmp / "stages"
    sensor_stages.main(args + ["--out", str(out)])
    tex = render.load_texture(args[5])
    name, png, truth = frames.make_frame("rig-sensor", 601, 0, SMALL, tex, supersample=1)
    assert camera.load_camera(out / "camera.json") == SMALL
    for v in sensor_stages.VARIANTS:
        d = out / v
        assert sorted(os.listdir(d)) == sorted([name, "truth.jsonl", "params.json"]), v
        assert (d / "truth.jsonl").read_text() == json.dumps(truth) + "\n", v
        assert json.loads((d / "params.json").read_text())["stages_off"] == list(sensor_stages.VARIANTS[v])
    assert (out / "all" / name).read_bytes() == png
    assert (out / "none" / name).read_bytes() != png
    # run again: every folder complete with the same parameters, reused untouched
    stamp = {v: os.stat(out / v / name).st_mtime_ns for v in sensor_stages.VARIANTS}
    sensor_stages.main(args + ["--out", str(out)])
    assert stamp == {v: os.stat(out / v / name).st_mtime_ns for v in sensor_stages.VARIANTS}


def test_others_folders_left_alone(setup):
    tmp, args = setup
    out = tmp / "measured"
    (out / "no-wb").mkdir(parents=True)
    (out / "no-wb" / "1_2_3.png").write_bytes(b"a frame of someone else's")
    with pytest.raises(SystemExit, match="no-wb: holds 1 PNG file"):
        sensor_stages.main(args + ["--out", str(out)])
    assert (out / "no-wb" / "1_2_3.png").read_bytes() == b"a frame of someone else's"
    other = tmp / "other"
    other.mkdir()
    (other / "camera.json").write_text(json.dumps(camera.Camera().to_dict()))
    with pytest.raises(SystemExit, match="another camera's file"):
        sensor_stages.main(args + ["--out", str(other)])
    assert camera.load_camera(other / "camera.json") == camera.Camera()
    assert os.listdir(other) == ["camera.json"]
