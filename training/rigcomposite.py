"""Rig-like frames by compositing: a sphere (rendered, or drawn) over a cluttered background
with a mounting post, vignetting, noise and JPEG. For testing and measuring the sphere
localisation (sphere-crop-v2) before, and beside, full rig scenes; the sphere's true circle
is known exactly.

A rendered sphere comes as two renders of the same pose, on black and on white: their
difference is the sphere's coverage of each pixel (anti-aliased rim included), so it can be
laid over any background.
"""
import math

import cv2
import numpy as np


def clutter(rng, h, w, level=None, blocks=40):
    """A non-uniform background: a brightness gradient at `level` (0-255, random if None) with
    rectangles, ellipses and lines of random colours and sizes, lightly blurred. BGR uint8."""
    level = float(rng.uniform(20, 235)) if level is None else float(level)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    a = rng.uniform(0, 2 * np.pi)
    g = (np.cos(a) * (xx / w - 0.5) + np.sin(a) * (yy / h - 0.5)) * rng.uniform(0, 120)
    img = np.clip(level + g, 0, 255)[..., None] * (1 + rng.uniform(-0.2, 0.2, 3))[None, None, :]
    img = np.clip(img, 0, 255).astype(np.uint8)
    for _ in range(blocks):
        col = tuple(int(v) for v in np.clip(level + rng.normal(0, 70, 3), 0, 255))
        kind = rng.integers(0, 3)
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        sz = int(rng.integers(8, max(9, min(h, w) // 3)))
        if kind == 0:
            cv2.rectangle(img, (x, y), (x + sz, y + int(sz * rng.uniform(0.3, 2))), col, -1)
        elif kind == 1:
            cv2.ellipse(img, (x, y), (sz // 2, max(1, int(sz // 2 * rng.uniform(0.15, 0.6)))), float(rng.uniform(0, 180)),
                        0, 360, col, -1, cv2.LINE_AA)
        else:
            cv2.line(img, (x, y), (int(rng.integers(0, w)), int(rng.integers(0, h))), col,
                     int(rng.integers(1, 6)), cv2.LINE_AA)
    return cv2.GaussianBlur(img, (0, 0), float(rng.uniform(0.5, 2.0)))


def post(img, cx, cy, r, rng, angle_deg=90.0, width_frac=None, colour=None):
    """Draw a mounting post from the sphere's centre outward in direction angle_deg (90: down,
    image coordinates), to the frame edge, shaded across its width, in place. The sphere laid
    over it afterwards hides its end, so it touches the rim."""
    h, w = img.shape[:2]
    width = r * (rng.uniform(0.25, 0.7) if width_frac is None else width_frac)
    base = np.asarray(colour if colour is not None else rng.integers(20, 235, 3), np.float64)
    a = math.radians(angle_deg)
    ux, uy = math.cos(a), math.sin(a)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    along = (xx - cx) * ux + (yy - cy) * uy
    across = -(xx - cx) * uy + (yy - cy) * ux
    # anti-aliased edges: coverage over a 1 px ramp
    cov = np.clip(width / 2 - np.abs(across) + 0.5, 0, 1) * (along > 0)
    shade = 0.55 + 0.45 * np.cos(np.clip(across / (width / 2), -1, 1) * 1.3)
    col = np.clip(base[None, None, :] * shade[..., None], 0, 255)
    out = img.astype(np.float64) * (1 - cov[..., None]) + col * cov[..., None]
    img[:] = np.clip(out + 0.5, 0, 255).astype(np.uint8)
    return img


def over(sphere_on_black, sphere_on_white, background):
    """The sphere laid over a background, from two renders of it on black and on white (BGR)."""
    b = sphere_on_black.astype(np.float64)
    wt = sphere_on_white.astype(np.float64)
    alpha = np.clip(1.0 - (wt - b).mean(axis=2) / 255.0, 0, 1)[..., None]
    out = b + (1 - alpha) * background.astype(np.float64)
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def drawn_sphere(h, w, cx, cy, r, rng, colour=None):
    """A drawn stand-in for a rendered sphere: (on black, on white) BGR images of a shaded,
    textured, anti-aliased disc of centre (cx, cy) (pixel centres at integers) and radius r."""
    ss = 4  # supersampling for the coverage
    yy, xx = np.mgrid[0:h * ss, 0:w * ss].astype(np.float64)
    X = (xx + 0.5) / ss - 0.5
    Y = (yy + 0.5) / ss - 0.5
    d2 = (X - cx) ** 2 + (Y - cy) ** 2
    inside = (d2 <= r * r).astype(np.float64)
    cov = inside.reshape(h, ss, w, ss).mean(axis=(1, 3))
    base = np.asarray(colour if colour is not None else rng.integers(60, 230, 3), np.float64)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    rr = np.sqrt(np.clip(1 - ((xx - cx) ** 2 + (yy - cy) ** 2) / (r * r), 0, 1))
    tex = np.zeros((h, w, 3), np.float64)
    tex[:] = base
    for _ in range(12):
        a, d = rng.uniform(0, 2 * np.pi), rng.uniform(0, r * 0.85)
        col = tuple(float(v) for v in rng.integers(0, 255, 3))
        cv2.circle(tex, (int(cx + d * np.cos(a)), int(cy + d * np.sin(a))), max(1, int(r * rng.uniform(0.05, 0.2))),
                   col, -1, cv2.LINE_AA)
    shaded = tex * (0.35 + 0.65 * rr)[..., None] * cov[..., None]
    on_black = np.clip(shaded + 0.5, 0, 255).astype(np.uint8)
    on_white = np.clip(shaded + 255.0 * (1 - cov[..., None]) + 0.5, 0, 255).astype(np.uint8)
    return on_black, on_white


def finish(img, rng, vignette=None, noise=None, gamma=None, jpeg=None):
    """Camera effects: vignetting (relative fall-off at the corners), Gaussian noise (sigma, levels),
    gamma, JPEG quality (None: each random; 0: off)."""
    h, w = img.shape[:2]
    f = img.astype(np.float64)
    v = rng.uniform(0, 0.45) if vignette is None else vignette
    if v:
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
        d2 = ((xx - w / 2) ** 2 + (yy - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
        f *= (1 - v * d2)[..., None]
    g = rng.uniform(0.8, 1.25) if gamma is None else gamma
    if g and g != 1:
        f = 255.0 * (np.clip(f, 0, 255) / 255.0) ** g
    n = rng.uniform(0, 4) if noise is None else noise
    if n:
        f += rng.normal(0, n, f.shape)
    out = np.clip(f + 0.5, 0, 255).astype(np.uint8)
    q = int(rng.integers(70, 96)) if jpeg is None else jpeg
    if q:
        ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, q])
        out = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    return out


def rig_frame(on_black, on_white, cx, cy, r, rng, post_angle=None, level=None, effects=True):
    """A rig-like frame: clutter at `level`, a post at post_angle (degrees, None: random near
    'down'), the sphere over both, then camera effects."""
    h, w = on_black.shape[:2]
    bg = clutter(rng, h, w, level)
    ang = float(rng.normal(90, 40)) if post_angle is None else post_angle
    post(bg, cx, cy, r, rng, ang)
    img = over(on_black, on_white, bg)
    return finish(img, rng) if effects else img
