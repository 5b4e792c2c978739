"""The checker's views see what the renderer draws: `sim render` (the fixed interface) against
the texture lookup of textures.views, on the reference camera."""
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from textures import generate, views
from textures.palette import find_palette, srgb8_to_lab

# Reference camera (conventions.md).
W, H, F, P, D, RADIUS = 640, 512, 16.0, 0.0096, 250.0, 20.0


def _sim_command():
    exe = os.path.join(os.path.dirname(sys.executable), "sim")
    return exe if os.path.exists(exe) else shutil.which("sim")


@pytest.mark.slow
def test_views_match_sim_render(tmp_path):
    exe = _sim_command()
    if exe is None:
        pytest.skip("sim command not installed")
    tex_path = tmp_path / "t3.png"
    rgb = generate.render(3, "color", 1024, 512)
    Image.fromarray(rgb).save(tex_path)
    pose = (10.0, 20.0, -15.0)
    out = tmp_path / "frame.png"
    r = subprocess.run([exe, "render", "--texture", str(tex_path), "--pose", *map(str, pose),
                        "--out", str(out)], capture_output=True, text=True, timeout=120)
    if r.returncode != 0 or not out.exists():
        pytest.skip(f"sim render unavailable here: {r.stderr.strip()[-200:]}")
    frame = np.asarray(Image.open(out).convert("RGB"))
    assert frame.shape[:2] == (H, W)
    # Rays of the central pixels of the sphere's image, intersected with the sphere.
    vv, uu = np.mgrid[0:H, 0:W]
    a = (uu + 0.5 - W / 2) * P / F
    b = -(vv + 0.5 - H / 2) * P / F
    q = a * a + b * b + 1.0
    disc = D * D - q * (D * D - RADIUS * RADIUS)
    hit = disc > 0
    t = (D - np.sqrt(np.where(hit, disc, 0.0))) / q
    world = np.stack([t * a, t * b, D - t], -1) / RADIUS
    central = hit & (world[..., 2] > 0.8)           # away from the shaded limb
    R = views.rotations(np.array([pose]))[0]
    lat, lon = views.lonlat_from_direction(world[central] @ R)     # R^T p for row vectors
    expected = views.sample_texture(srgb8_to_lab(rgb), lat, lon)
    pal = find_palette(rgb)
    label = lambda lab: np.argmin(((lab[:, None, :] - pal.lab[None]) ** 2).sum(2), 1)
    agree = (label(expected) == label(srgb8_to_lab(frame[central]))).mean()
    assert central.sum() > 5000 and agree > 0.9, agree
