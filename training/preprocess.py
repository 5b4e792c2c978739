"""Preprocessing "sphere-crop-v1": a camera frame -> the network input tensor.

The one Python implementation (docs/interfaces.md gives the algorithm step
by step; host/ implements the same steps in C++ and is tested against this).
Its parameters are written into every exported model's metadata.
"""
import json
import math

import cv2
import numpy as np

NAME = "sphere-crop-v1"
DEFAULTS = {
    "name": NAME,
    "size": 128,
    "margin": 1.15,
    "fg_threshold": 40,
    "border_frac": 0.02,
    "close_frac": 0.03,
    "min_area_frac": 0.002,
    "mean": [0.485, 0.456, 0.406],
    "std": [0.229, 0.224, 0.225],
}


class NoSphere(ValueError):
    """The frame holds nothing that looks like the sphere."""


def params(overrides=None):
    """Preprocessing parameters: the defaults updated by `overrides` (dict or JSON text)."""
    p = dict(DEFAULTS)
    if overrides:
        p.update(json.loads(overrides) if isinstance(overrides, str) else overrides)
    if p["name"] != NAME:
        raise ValueError(f"unknown preprocessing {p['name']!r}; this code implements {NAME!r}")
    return p


def _as_bgr(frame):
    if frame.ndim == 2:
        return cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    if frame.shape[2] == 4:
        return cv2.cvtColor(frame, cv2.COLOR_BGRA2BGR)
    return frame


def background_colour(frame, p):
    """Per-channel median of the border band (step 1)."""
    h, w = frame.shape[:2]
    b = max(2, math.floor(p["border_frac"] * min(h, w) + 0.5))
    band = np.concatenate([
        frame[:b].reshape(-1, 3), frame[h - b:].reshape(-1, 3),
        frame[b:h - b, :b].reshape(-1, 3), frame[b:h - b, w - b:].reshape(-1, 3)])
    return np.median(band.astype(np.float64), axis=0)


def find_sphere(frame, p=None):
    """(cx, cy, r, bg) of the sphere in a BGR uint8 frame (steps 1-5); NoSphere if there is none."""
    p = p or DEFAULTS
    frame = _as_bgr(frame)
    h, w = frame.shape[:2]
    bg = background_colour(frame, p)
    # max over channels of |I_c - bg_c|, channel by channel (numpy's max over a length-3 last axis
    # is slow); float32 is exact here: I_c is an integer and bg_c an integer or a half
    f = frame.astype(np.float32)
    diff = np.abs(f[:, :, 0] - np.float32(bg[0]))
    for c in (1, 2):
        np.maximum(diff, np.abs(f[:, :, c] - np.float32(bg[c])), out=diff)
    mask = np.where(diff > p["fg_threshold"], 255, 0).astype(np.uint8)
    k = 2 * math.floor(p["close_frac"] * min(h, w) / 2) + 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, kernel)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    best, best_area = None, -1.0
    for c in contours:
        a = cv2.contourArea(c)
        if a > best_area:
            best, best_area = c, a
    if best is None or best_area < p["min_area_frac"] * h * w:
        raise NoSphere("no sphere found in frame")
    # the hull has the same enclosing circle as the contour, from a tenth of the points
    (cx, cy), r = cv2.minEnclosingCircle(cv2.convexHull(best))
    return cx, cy, r, bg


def crop(frame, cx, cy, r, bg, p=None):
    """Square crop around the circle, outside filled with bg, resized to size x size (steps 6-7)."""
    p = p or DEFAULTS
    frame = _as_bgr(frame)
    h, w = frame.shape[:2]
    half = r * p["margin"]
    x0 = math.floor(cx - half + 0.5)
    y0 = math.floor(cy - half + 0.5)
    side = max(1, math.floor(2 * half + 0.5))
    pad_l, pad_t = max(0, -x0), max(0, -y0)
    pad_r, pad_b = max(0, x0 + side - w), max(0, y0 + side - h)
    fill = [int(np.clip(math.floor(v + 0.5), 0, 255)) for v in bg]
    padded = cv2.copyMakeBorder(frame, pad_t, pad_b, pad_l, pad_r, cv2.BORDER_CONSTANT, value=fill)
    roi = padded[y0 + pad_t:y0 + pad_t + side, x0 + pad_l:x0 + pad_l + side]
    return cv2.resize(roi, (p["size"], p["size"]), interpolation=cv2.INTER_AREA)


def normalise(crop_bgr, p=None):
    """BGR uint8 crop -> float32 CHW tensor, RGB, (v/255 - mean) / std (step 8)."""
    p = p or DEFAULTS
    rgb = cv2.cvtColor(crop_bgr, cv2.COLOR_BGR2RGB).astype(np.float32) / 255.0
    rgb = (rgb - np.asarray(p["mean"], np.float32)) / np.asarray(p["std"], np.float32)
    return np.ascontiguousarray(rgb.transpose(2, 0, 1))


def preprocess(frame, p=None):
    """Full frame (BGR uint8) -> float32 [3, size, size] network input."""
    p = p or DEFAULTS
    cx, cy, r, bg = find_sphere(frame, p)
    return normalise(crop(frame, cx, cy, r, bg, p), p)


def preprocess_file(path, p=None):
    """Read an image file and preprocess it; errors name the file."""
    frame = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if frame is None:
        raise ValueError(f"{path}: cannot decode image (missing, corrupt or not an image)")
    if frame.dtype != np.uint8:
        raise ValueError(f"{path}: expected 8-bit pixels, got {frame.dtype}")
    try:
        return preprocess(frame, p)
    except NoSphere as e:
        raise NoSphere(f"{path}: {e}") from None
