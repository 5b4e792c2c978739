import json
from pathlib import Path

import cv2
import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
VECTORS = REPO / "tests" / "data" / "conventions_vectors.json"  # docs/conventions.md


@pytest.fixture(scope="session")
def vectors():
    # Part of the repository: a missing file is a failure (open raises), never a skip.
    return json.loads(VECTORS.read_text())


def disc_frame(seed=0, w=160, h=128, bg=(64, 64, 70)):
    """A test frame (not a render): a noisy-coloured disc on a plain background."""
    rng = np.random.default_rng(seed)
    img = np.empty((h, w, 3), np.uint8)
    img[:] = bg
    tex = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    mask = np.zeros((h, w), np.uint8)
    cv2.circle(mask, (w // 2 + 3, h // 2 - 2), 40, 255, -1)
    img[mask > 0] = tex[mask > 0] | 128
    return img


@pytest.fixture
def frame():
    """Factory for test frames: frame(seed) -> BGR uint8 disc image."""
    return disc_frame
