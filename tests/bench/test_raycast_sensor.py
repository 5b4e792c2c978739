"""The ray-caster's `rig-sensor` family (bench/raycast/families.py, sensor.py): the rig's scene through a
colour camera's pipeline. The family draws and draws again identically from (seed, index); each stage
does what it says on a tiny synthetic image (that every family keeps its seed stream, and that no
other family's scene has a sensor: test_raycast_streams.py)."""
import os
import sys

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "bench"))

from raycast import camera, frames, render, sensor  # noqa: E402

# A quarter of the reference frame with 4x the pixel pitch (sphere radius about 33 px): fast.
SMALL = camera.Camera(width=160, height=128, pixel_mm=0.0384)


def test_family_draws_again_identically(tmp_path):
    tex = np.random.default_rng(3).uniform(0, 1, (64, 128, 3)).astype(np.float32)
    a = frames.make_frame("rig-sensor", 601, 4, SMALL, tex, supersample=2)
    b = frames.make_frame("rig-sensor", 601, 4, SMALL, tex, supersample=2)
    assert a[0] == b[0] and a[1] == b[1] and a[2] == b[2]
    sen = a[2]["scene"]["sensor"]
    assert sen["cfa"] in sensor.CFA_LAYOUTS and sen["demosaic"] in sensor.DEMOSAIC
    for k in ("red", "blue"):
        assert sensor.CA_RANGE[0] <= abs(sen["ca"][k] - 1) <= sensor.CA_RANGE[1]
    assert all(sensor.WB_RANGE[0] <= g <= sensor.WB_RANGE[1] for g in sen["wb"])
    # the truth is the green (reference) outline: the pipeline does not move it
    assert a[2]["circle"] == [round(c, 4) for c in render.circle(a[2]["scene"], SMALL)]
    # the rest of the scene is the rig family's kind of scene
    assert a[2]["scene"]["mount"]["type"] == "post"
    c = frames.make_frame("rig-sensor", 601, 5, SMALL, tex, supersample=2)
    assert c[2]["scene"]["sensor"] != sen


def _edge_x(channel):
    """Where a row's profile crosses half way between its ends (sub-pixel, continuous pixels)."""
    row = channel.astype(np.float64)
    lo, hi = row[0], row[-1]
    k = int(np.argmax((row - lo) / (hi - lo) >= 0.5))
    t = (lo + (hi - lo) / 2 - row[k - 1]) / (row[k] - row[k - 1])
    return k - 1 + t + 0.5


def test_lateral_ca_moves_red_and_not_green():
    img = np.zeros((8, 200, 3), np.float32)
    img[:, 150:] = 1.0                                   # a vertical edge 50 px right of the centre
    out = sensor.lateral_ca(img, 1.01, 0.99, (100.0, 4.0))
    assert np.array_equal(out[..., 1], img[..., 1])
    assert _edge_x(img[4, :, 1]) == pytest.approx(150.0, abs=1e-6)
    assert _edge_x(out[4, :, 0]) == pytest.approx(150.5, abs=0.01)      # 50 px * 1.01: red moves out
    assert _edge_x(out[4, :, 2]) == pytest.approx(149.5, abs=0.01)      # blue moves in
    same = sensor.lateral_ca(img, 1.0, 1.0, (100.0, 4.0))
    assert np.allclose(same, img)


@pytest.mark.parametrize("layout", sensor.CFA_LAYOUTS)
@pytest.mark.parametrize("method", list(sensor.DEMOSAIC))
def test_mosaic_and_demosaic_of_a_flat_colour_is_flat(layout, method):
    rgb = np.array([200, 90, 40], np.uint8)
    img = np.broadcast_to(rgb / 255.0, (16, 20, 3)).astype(np.float32)
    raw = sensor.mosaic(img, layout)
    assert raw.shape == (16, 20)
    idx = sensor.channel_map(layout, 16, 20)
    assert idx[0, 0] == "RGB".index(layout[0]) and idx[1, 1] == "RGB".index(layout[3])
    raw8 = np.floor(raw * 255 + 0.5).astype(np.uint8)
    out = sensor.demosaic(raw8, layout, method)
    assert np.array_equal(out[2:-2, 2:-2], np.broadcast_to(rgb, (12, 16, 3)))


def test_unsharp_overshoots_both_sides_of_an_edge():
    img = np.zeros((5, 40), np.float32) + 0.2
    img[:, 20:] = 0.8
    out = sensor.unsharp(img, 1.0, 1.0)
    assert out[2, 19] < 0.2 - 0.05 and out[2, 20] > 0.8 + 0.05        # halo on both sides
    assert out[2, 0] == pytest.approx(0.2, abs=1e-6) and out[2, -1] == pytest.approx(0.8, abs=1e-6)
    assert np.array_equal(sensor.unsharp(img, 0.0, 1.0), img)


def test_white_balance_gains_and_clipping():
    img = np.broadcast_to(np.float32([0.5, 0.5, 0.9]), (8, 8, 3)).copy()
    scene = {"seed": 1, "gamma": 1.0, "noise": None, "jpeg": 0,
             "sensor": {"ca": {"red": 1.0, "blue": 1.0}, "cfa": "RGGB", "demosaic": "bilinear",
                        "wb": [1.2, 1.0, 1.25], "sharpen": None}}
    out = sensor.pipeline(img, scene, SMALL.at(), off=("cfa",))
    assert out[4, 4].tolist() == [153, 128, 255]                           # 0.6, 0.5, clipped
    out = sensor.pipeline(img, scene, SMALL.at(), off=("cfa", "wb"))
    assert out[4, 4].tolist() == [128, 128, 230]
    with pytest.raises(ValueError, match="unknown sensor stage"):
        sensor.pipeline(img, scene, SMALL.at(), off=("lens",))
