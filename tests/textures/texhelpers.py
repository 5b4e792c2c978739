"""Helpers for the textures tests."""
import numpy as np

TEST_HEIGHT = 256      # 512 x 256: every criterion is measurable at this size
TEST_STEP = 6.0        # uniqueness grid step for the six-texture verdicts (P1 uses 3)


def bw_image(mask):
    """RGB uint8 image: black where mask, white elsewhere."""
    return np.where(mask[..., None], 0, 255).astype(np.uint8).repeat(3, 2)
