"""Helpers shared by the poseinfer program tests (a module name of their own:
every test folder has a conftest.py)."""
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def sphere_frame(h=512, w=640, cx=320, cy=256, r=133, seed=0, bg=(35, 45, 55), gray=False, noise=6):
    """A synthetic frame: noisy background, a coloured disc with blobs on it."""
    rng = np.random.default_rng(seed)
    img = np.empty((h, w, 3), np.uint8)
    img[:] = bg
    if noise:
        img += rng.integers(0, noise, img.shape, dtype=np.uint8)
    cv2.circle(img, (cx, cy), r, (210, 130, 40), -1, lineType=cv2.LINE_AA)
    for _ in range(14):
        a, d = rng.uniform(0, 2 * np.pi), rng.uniform(0, r * 0.8)
        colour = tuple(int(v) for v in rng.integers(0, 255, 3))
        cv2.circle(img, (int(cx + d * np.cos(a)), int(cy + d * np.sin(a))), max(1, int(r * 0.15)), colour, -1,
                   lineType=cv2.LINE_AA)
    if gray:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    return img


def dots_texture(path, seed=3):
    """A texture for `sim render` / `sim vcam`: 60 coloured dots on light gray, written to path."""
    rng = np.random.default_rng(seed)
    t = np.full((256, 512, 3), 230, np.uint8)
    for _ in range(60):
        cv2.circle(t, (int(rng.integers(0, 512)), int(rng.integers(0, 256))), int(rng.integers(5, 30)),
                   tuple(int(v) for v in rng.integers(0, 255, 3)), -1)
    cv2.imwrite(str(path), t)
    return path
