"""Reading a texture image a user brings, with errors that name the file and the problem."""
import os

import numpy as np
from PIL import Image, UnidentifiedImageError

MIN_HEIGHT = 32


class TextureError(Exception):
    """A texture file that cannot be used; the message names the file and what is wrong."""


def load_texture(path, require_png=False):
    """8-bit RGB array [H, W, 3] of an equirectangular texture (width = 2 x height).

    Any format Pillow reads (PNG, JPEG, ...) unless require_png; alpha is
    dropped, gray and palette images are expanded, 16-bit images scaled to 8 bits.
    """
    if not os.path.isfile(path):
        raise TextureError(f"{path}: no such file")
    try:
        with Image.open(path) as im:
            fmt = im.format
            im.load()
            if im.mode in ("I;16", "I;16B", "I;16L", "I"):
                arr = np.asarray(im, dtype=np.float64)
                arr = np.clip(arr / (257.0 if arr.max() > 255 else 1.0), 0, 255).astype(np.uint8)
                im = Image.fromarray(arr, "L")
            rgb = np.asarray(im.convert("RGB"))
    except (UnidentifiedImageError, OSError, ValueError) as e:
        raise TextureError(f"{path}: not a readable image ({e.__class__.__name__}: {e})") from None
    if require_png and fmt != "PNG":
        raise TextureError(f"{path}: a PNG texture is needed, this file is {fmt}")
    h, w = rgb.shape[:2]
    if w != 2 * h:
        raise TextureError(f"{path}: {w} x {h} pixels; an equirectangular texture is twice as wide as high "
                           f"(e.g. 2048 x 1024)")
    if h < MIN_HEIGHT:
        raise TextureError(f"{path}: {w} x {h} pixels is too small; at least {2 * MIN_HEIGHT} x {MIN_HEIGHT}")
    return np.ascontiguousarray(rgb)
