"""Backdrops behind the sphere, as float32 RGB [H, W, 3] in 0..1, from a parameter dict.

Kinds: `uniform` (any brightness), `gradient` (linear), `clutter` (shapes of
a lab bench: boxes, cables, round parts, slightly out of focus), `noise`
(smooth multi-scale noise in a few colours: photo-like), `stripes`,
`checker`, `photo` (a real photograph bundled with scikit-image or
matplotlib, zoomed, cropped, maybe mirrored, brightened or dimmed, slightly
out of focus). A kind's parameters are drawn by `draw(kind, rng, ...)` and
stored in the frame's scene record, so `make(params, w, h)` draws it again.
Hard-edged patterns are drawn at twice the size and reduced by area
averaging, as a camera's pixels integrate them.
"""
import math
import os

import cv2
import numpy as np

KINDS = ("uniform", "gradient", "clutter", "noise", "stripes", "checker", "photo")

# Real photographs shipped inside pinned packages (nothing is downloaded): name -> (package, file in its
# data folder). Photographs only; the packages' synthetic images (logo, chessboard, phantom, color, horse,
# text, page, clock_motion) are left out.
PHOTOS = {
    "astronaut": ("skimage", "astronaut.png"), "camera": ("skimage", "camera.png"),
    "coffee": ("skimage", "coffee.png"), "chelsea": ("skimage", "chelsea.png"),
    "rocket": ("skimage", "rocket.jpg"), "motorcycle_left": ("skimage", "motorcycle_left.png"),
    "motorcycle_right": ("skimage", "motorcycle_right.png"), "coins": ("skimage", "coins.png"),
    "moon": ("skimage", "moon.png"), "brick": ("skimage", "brick.png"), "grass": ("skimage", "grass.png"),
    "gravel": ("skimage", "gravel.png"), "retina": ("skimage", "retina.jpg"),
    "hubble_deep_field": ("skimage", "hubble_deep_field.jpg"), "ihc": ("skimage", "ihc.png"),
    "cell": ("skimage", "cell.png"), "grace_hopper": ("matplotlib", "grace_hopper.jpg"),
}
PHOTO_ZOOM = (1.0, 2.5)      # x the smallest scale that covers the frame
PHOTO_GAIN = (0.6, 1.4)      # brightness gain on the photo's values
PHOTO_BLUR_PX = (0.5, 2.0)   # Gaussian sigma: the backdrop lies behind the focus plane
_PHOTO_CACHE = {}


def _colour(rng, lo=0.0, hi=1.0):
    """A colour of brightness in [lo, hi] with a random tint."""
    level = rng.uniform(lo, hi)
    tint = rng.normal(0.0, 0.08, 3)
    return [float(np.clip(level + t, 0.0, 1.0)) for t in tint]


def draw(kind, rng, width, height):
    """Random parameters of a backdrop of `kind`."""
    if kind == "uniform":
        return {"kind": kind, "colour": _colour(rng)}
    if kind == "gradient":
        return {"kind": kind, "a": _colour(rng), "b": _colour(rng), "angle_deg": float(rng.uniform(0, 360))}
    if kind == "clutter":
        shapes = []
        for _ in range(int(rng.integers(8, 30))):
            shapes.append({"shape": str(rng.choice(["rect", "ellipse", "line"])),
                           "x": float(rng.uniform(-0.1, 1.1) * width), "y": float(rng.uniform(-0.1, 1.1) * height),
                           "w": float(rng.uniform(0.03, 0.4) * width), "h": float(rng.uniform(0.03, 0.4) * height),
                           "angle_deg": float(rng.uniform(0, 180)), "colour": _colour(rng),
                           "thick": int(rng.integers(2, 14))})
        return {"kind": kind, "base": _colour(rng), "shapes": shapes, "blur_px": float(rng.uniform(0.5, 3.0))}
    if kind == "noise":
        return {"kind": kind, "seed": int(rng.integers(0, 2**31)), "colours": [_colour(rng) for _ in range(3)],
                "scale_px": float(rng.uniform(20, 160)), "octaves": int(rng.integers(2, 5))}
    if kind == "stripes":
        return {"kind": kind, "a": _colour(rng), "b": _colour(rng), "period_px": float(rng.uniform(6, 80)),
                "angle_deg": float(rng.uniform(0, 180)), "square": bool(rng.random() < 0.5)}
    if kind == "checker":
        return {"kind": kind, "a": _colour(rng), "b": _colour(rng), "cell_px": float(rng.uniform(8, 60)),
                "angle_deg": float(rng.uniform(0, 90))}
    if kind == "photo":
        names = sorted(PHOTOS)
        return {"kind": kind, "photo": names[int(rng.integers(len(names)))],
                "zoom": float(rng.uniform(*PHOTO_ZOOM)), "crop": [float(rng.random()), float(rng.random())],
                "flip": bool(rng.random() < 0.5), "gain": float(rng.uniform(*PHOTO_GAIN)),
                "blur_px": float(rng.uniform(*PHOTO_BLUR_PX))}
    raise ValueError(f"unknown background kind {kind!r} (valid: {', '.join(KINDS)})")


def photo_path(name):
    """The file of a bundled photograph, inside its package's installed data."""
    if name not in PHOTOS:
        raise ValueError(f"unknown photo {name!r} (valid: {', '.join(sorted(PHOTOS))})")
    package, file = PHOTOS[name]
    if package == "skimage":
        import skimage
        return os.path.join(os.path.dirname(skimage.__file__), "data", file)
    import matplotlib
    return os.path.join(matplotlib.get_data_path(), "sample_data", file)


def load_photo(name):
    """A bundled photograph as float32 RGB in 0..1 (grey photos as grey RGB), its 8-bit values / 255.

    Colour space: the renderer treats a backdrop's values like the texture's (its PNG values / 255 taken
    as they are): exposure and vignetting scale them, then the frame gets value ** (1 / gamma) with gamma
    near 1 and 8 bits, with no sRGB encoding. So the values are display values, and the photo's 8-bit
    sRGB values are used unconverted: at gain 1, exposure 1 and gamma 1 a pixel comes back as in the
    photo. (Converting to linear light would darken and harden every photo, as nothing re-encodes it.)"""
    if name not in _PHOTO_CACHE:
        path = photo_path(name)
        img = cv2.imread(path, cv2.IMREAD_COLOR)      # grey files come back as three equal channels
        if img is None:
            raise ValueError(f"{path}: cannot read the photo {name!r} (is its package installed?)")
        _PHOTO_CACHE[name] = cv2.cvtColor(img, cv2.COLOR_BGR2RGB).astype(np.float32) / 255.0
    return _PHOTO_CACHE[name]


def _photo(p, width, height):
    """The photo scaled by zoom x the smallest scale that covers the frame, mirrored if `flip`, the
    frame's window placed at `crop` (0..1 of the room left in each direction), times `gain`, blurred."""
    img = load_photo(p["photo"])
    if p["flip"]:
        img = img[:, ::-1]
    ph, pw = img.shape[:2]
    scale = max(width / pw, height / ph) * p["zoom"]
    rw, rh = max(width, int(math.ceil(pw * scale))), max(height, int(math.ceil(ph * scale)))
    img = cv2.resize(np.ascontiguousarray(img), (rw, rh),
                     interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_CUBIC)
    x0 = int(round(p["crop"][0] * (rw - width)))
    y0 = int(round(p["crop"][1] * (rh - height)))
    img = np.clip(img[y0:y0 + height, x0:x0 + width] * np.float32(p["gain"]), 0.0, 1.0)
    return cv2.GaussianBlur(img, (0, 0), p["blur_px"], borderType=cv2.BORDER_REFLECT)


def _grid(width, height, scale=1):
    ys, xs = np.mgrid[0:height * scale, 0:width * scale].astype(np.float32)
    return (xs + 0.5) / scale, (ys + 0.5) / scale


def _mix(a, b, w):
    a = np.asarray(a, np.float32)
    b = np.asarray(b, np.float32)
    return a * (1.0 - w[..., None]) + b * w[..., None]


def _reduce(img, scale):
    h, w = img.shape[0] // scale, img.shape[1] // scale
    return cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)


def make(p, width, height):
    kind = p["kind"]
    if kind == "uniform":
        return np.broadcast_to(np.asarray(p["colour"], np.float32), (height, width, 3)).copy()
    if kind == "gradient":
        x, y = _grid(width, height)
        a = np.radians(p["angle_deg"])
        s = (x - width / 2) * np.cos(a) + (y - height / 2) * np.sin(a)
        w = (s - s.min()) / max(float(s.max() - s.min()), 1e-6)
        return _mix(p["a"], p["b"], w)
    if kind == "clutter":
        img = np.empty((height * 2, width * 2, 3), np.float32)
        img[:] = p["base"]
        for s in p["shapes"]:
            c = tuple(float(v) for v in s["colour"])
            centre = (s["x"] * 2, s["y"] * 2)
            size = (s["w"] * 2, s["h"] * 2)
            if s["shape"] == "rect":
                box = cv2.boxPoints((centre, size, s["angle_deg"]))
                cv2.fillPoly(img, [np.round(box * 16).astype(np.int32)], c, cv2.LINE_8, shift=4)
            elif s["shape"] == "ellipse":
                cv2.ellipse(img, (centre, size, s["angle_deg"]), c, -1, cv2.LINE_8)
            else:
                a = np.radians(s["angle_deg"])
                dx, dy = np.cos(a) * size[0], np.sin(a) * size[0]
                p0 = (int(centre[0] - dx), int(centre[1] - dy))
                p1 = (int(centre[0] + dx), int(centre[1] + dy))
                cv2.line(img, p0, p1, c, s["thick"] * 2, cv2.LINE_8)
        img = _reduce(img, 2)
        return cv2.GaussianBlur(img, (0, 0), p["blur_px"])
    if kind == "noise":
        rng = np.random.default_rng(p["seed"])
        field = np.zeros((height, width), np.float32)
        amp, total = 1.0, 0.0
        scale = p["scale_px"]
        for _ in range(p["octaves"]):
            gw, gh = max(2, int(width / scale) + 2), max(2, int(height / scale) + 2)
            coarse = rng.random((gh, gw)).astype(np.float32)
            field += amp * cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC)
            total += amp
            amp *= 0.5
            scale /= 2.0
        field = np.clip(field / total, 0.0, 1.0)
        field = (field - field.min()) / max(float(field.max() - field.min()), 1e-6)
        c = np.asarray(p["colours"], np.float32)
        lo = _mix(c[0], c[1], np.clip(field * 2.0, 0, 1))
        return np.where((field < 0.5)[..., None], lo, _mix(c[1], c[2], np.clip(field * 2.0 - 1.0, 0, 1)))
    if kind == "stripes":
        x, y = _grid(width, height, 2)
        a = np.radians(p["angle_deg"])
        phase = (x * np.cos(a) + y * np.sin(a)) / p["period_px"]
        if p["square"]:
            w = (np.mod(phase, 1.0) < 0.5).astype(np.float32)
        else:
            w = 0.5 + 0.5 * np.sin(2 * np.pi * phase)
        return _reduce(_mix(p["a"], p["b"], w), 2)
    if kind == "checker":
        x, y = _grid(width, height, 2)
        a = np.radians(p["angle_deg"])
        xr = (x * np.cos(a) + y * np.sin(a)) / p["cell_px"]
        yr = (-x * np.sin(a) + y * np.cos(a)) / p["cell_px"]
        w = ((np.floor(xr) + np.floor(yr)) % 2).astype(np.float32)
        return _reduce(_mix(p["a"], p["b"], w), 2)
    if kind == "photo":
        return _photo(p, width, height)
    raise ValueError(f"unknown background kind {kind!r} (valid: {', '.join(KINDS)})")
