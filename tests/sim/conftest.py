"""Shared fixtures of the sim tests: small synthetic textures (the paper's textures come from textures/)."""
import numpy as np
import pytest
from PIL import Image


def stripe_texture(h=256):
    """A small equirectangular test texture: light grey with dark grid lines and two colour patches."""
    w = 2 * h
    tex = np.full((h, w, 3), 230, np.uint8)
    tex[:, :: w // 16] = 0
    tex[:: h // 8, :] = 0
    tex[h // 5: h // 3, w // 4: w // 2] = (0, 128, 0)
    tex[h // 2: 3 * h // 4, w // 2: 3 * w // 4] = (0, 0, 255)
    return tex


@pytest.fixture(scope="session")
def stripe_rgb():
    return stripe_texture()


@pytest.fixture(scope="session")
def texture_png(tmp_path_factory):
    path = tmp_path_factory.mktemp("tex") / "stripes.png"
    Image.fromarray(stripe_texture()).save(path)
    return str(path)


@pytest.fixture(scope="session")
def small_camera_json(tmp_path_factory):
    """A 160 x 128 camera (the reference camera at a quarter of the resolution)."""
    path = tmp_path_factory.mktemp("cam") / "small.json"
    path.write_text('{"width": 160, "height": 128, "pixel_mm": 0.0384}')
    return str(path)
