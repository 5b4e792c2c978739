"""Backgrounds of rig scenes: flat, gradient, procedural clutter, or a photo of the user's lab.

A frame's background comes from its draw (sim/scene.draw: kind, two colours,
blur, a seed) and the scene's ranges for the clutter; everything random in it
comes from default_rng(seed), so the frame stays a function of its draw.

- flat: the draw's colour.
- gradient: colour -> color2, linear at a random angle or radial from a random
  centre (half each).
- clutter: a flat or gradient base mottled by smooth noise (blotches 16 to
  96 px across, amplitude up to 25 levels), then N shapes (rotated rectangles, ellipses,
  thick lines, triangles) of the scene's shape colours (any brightness) and
  sizes (a fraction of the frame's larger side), drawn antialiased.
- photo: the draw's image of the photos folder, scaled to cover the frame
  (x 1 to 1.6), a random crop, flipped half the time, times photo_gain.
Then a Gaussian blur of blur_px (an out-of-focus background).
"""
import math

import cv2
import numpy as np

from sim.scene import _color


_GRID = {}


def _grid(w, h):
    g = _GRID.get((w, h))
    if g is None:
        g = _GRID[(w, h)] = np.mgrid[0:h, 0:w].astype(np.float32)
    return g


def _gradient(rng, w, h, c1, c2):
    """c1 -> c2, linear at a random angle or radial from a random centre (half each). Computed on a grid
    of every 8th pixel and interpolated bilinearly: exact for the linear ramp, within a level for the
    radial one (whose only kink, at its centre, the interpolation rounds off)."""
    step = 8
    gw, gh = w // step + 2, h // step + 2
    yy, xx = np.mgrid[0:gh, 0:gw].astype(np.float32) * step
    if rng.uniform() < 0.5:
        a = rng.uniform(0.0, 2.0 * math.pi)
        t = xx * math.cos(a) + yy * math.sin(a)
    else:
        cx, cy = rng.uniform(0, w), rng.uniform(0, h)
        t = np.hypot(xx - cx, yy - cy)
    inside = t[: h // step + 1, : w // step + 1]
    t = (t - inside.min()) / max(float(inside.max() - inside.min()), 1e-6)
    c1, c2 = np.asarray(c1, np.float32), np.asarray(c2, np.float32)
    coarse = (c1 + (c2 - c1) * np.clip(t, 0.0, 1.0)[..., None]).astype(np.float32)
    fx, fy = _grid(w, h)[1] / step, _grid(w, h)[0] / step
    return cv2.remap(coarse, fx, fy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _shapes(rng, img, spec):
    h, w = img.shape[:2]
    n = int(rng.integers(spec["shapes"][0], spec["shapes"][1] + 1))
    big = max(w, h)
    for _ in range(n):
        color = tuple(float(c) for c in _color(rng, spec["shape_color"]))
        size = rng.uniform(*spec["shape_size_frac"]) * big
        cx, cy = rng.uniform(-0.1 * w, 1.1 * w), rng.uniform(-0.1 * h, 1.1 * h)
        kind = int(rng.integers(0, 4))
        angle = rng.uniform(0.0, 180.0)
        aspect = rng.uniform(0.15, 1.0)
        if kind == 0:    # rotated rectangle (a box, a shelf, a cable duct)
            box = cv2.boxPoints(((cx, cy), (size, size * aspect), angle))
            cv2.fillPoly(img, [np.round(box * 16).astype(np.int32)], color, cv2.LINE_AA, shift=4)
        elif kind == 1:  # ellipse
            cv2.ellipse(img, (int(cx * 16), int(cy * 16)), (int(size * 8), int(size * aspect * 8)), angle,
                        0, 360, color, -1, cv2.LINE_AA, shift=4)
        elif kind == 2:  # thick line (a cable, an edge)
            dx, dy = math.cos(math.radians(angle)) * size, math.sin(math.radians(angle)) * size
            thick = max(1, int(rng.uniform(1, max(2.0, 0.08 * size))))
            cv2.line(img, (int((cx - dx) * 16), int((cy - dy) * 16)), (int((cx + dx) * 16), int((cy + dy) * 16)),
                     color, thick, cv2.LINE_AA, shift=4)
        else:            # triangle
            pts = np.array([[cx, cy]] * 3) + rng.uniform(-size, size, size=(3, 2))
            cv2.fillPoly(img, [np.round(pts * 16).astype(np.int32)], color, cv2.LINE_AA, shift=4)


_PHOTOS = {}  # path -> RGB uint8, decoded once per process


def _photo(path):
    img = _PHOTOS.get(path)
    if img is None:
        bgr = cv2.imread(path, cv2.IMREAD_COLOR)
        if bgr is None:
            raise ValueError(f"{path}: cannot read background photo")
        img = _PHOTOS[path] = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    return img


def _photo_background(rng, w, h, img, gain):
    ph, pw = img.shape[:2]
    s = max(w / pw, h / ph) * rng.uniform(1.0, 1.6)
    sw, sh = max(w, int(math.ceil(pw * s))), max(h, int(math.ceil(ph * s)))
    scaled = cv2.resize(img, (sw, sh), interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR)
    x0, y0 = int(rng.integers(0, sw - w + 1)), int(rng.integers(0, sh - h + 1))
    out = scaled[y0:y0 + h, x0:x0 + w].astype(np.float32)
    if rng.uniform() < 0.5:
        out = out[:, ::-1]
    return np.clip(out * gain, 0, 255)


def make_background(b, spec, photos, width, height):
    """float32 RGB [H, W, 3] in 0..255 of background draw `b` (scene.background ranges `spec`)."""
    rng = np.random.default_rng(b["seed"])
    kind = b["kind"]
    if kind == "photo":
        path = next(p for p in photos if p.endswith("/" + b["photo"]) or p == b["photo"])
        img = _photo_background(rng, width, height, _photo(path), b["photo_gain"])
    elif kind == "flat":
        img = np.empty((height, width, 3), np.float32)
        img[:] = np.asarray(b["color"], np.float32)
    elif kind == "gradient":
        img = _gradient(rng, width, height, b["color"], b["color2"])
    else:  # clutter on a flat or gradient base, mottled by smooth noise (walls, benches, cloth)
        if rng.uniform() < 0.5:
            base = np.empty((height, width, 3), np.float32)
            base[:] = np.asarray(b["color"], np.float32)
        else:
            base = _gradient(rng, width, height, b["color"], b["color2"])
        cell = int(rng.integers(16, 97))
        blotches = rng.normal(0.0, rng.uniform(0.0, 25.0), size=(height // cell + 2, width // cell + 2, 3))
        base += cv2.resize(blotches.astype(np.float32), (width, height), interpolation=cv2.INTER_CUBIC)
        img = np.clip(np.rint(base), 0, 255).astype(np.uint8)
        _shapes(rng, img, spec)
        img = img.astype(np.float32)
    if b["blur_px"] > 0.05 and kind in ("clutter", "photo"):  # flat and gradient are smooth already
        img = cv2.GaussianBlur(img, (0, 0), b["blur_px"])
    return img
