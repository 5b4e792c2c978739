"""The camera's image chain of a rig scene: composite, optics, sensor, encoding.

Order (what a real camera does): the rendered objects over the background
(alpha), lens blur (defocus: a uniform disc of radius defocus_px) and motion
blur (a line of motion_px at motion_deg), vignetting (gain 1 - v rr^2, rr the
distance from the principal point over the half diagonal), exposure (gain),
sensor noise (Gaussian, sigma^2 = read_noise^2 + shot_noise^2 x, x the
signal in 0..1, levels of 8 bits), gamma (out = in^(1/gamma)), rounding to 8
bits, then a JPEG round trip at jpeg_quality when the scene asks for one
(the frame is still written as PNG: the JPEG's artefacts, lossless).
Noise comes from default_rng(noise_seed) of the frame's draw.
"""
import math

import cv2
import numpy as np


def disc_kernel(radius):
    """Normalised uniform disc of `radius` px, pixel coverage by 8 x 8 supersampling."""
    n = int(math.ceil(radius + 0.5))
    ss = 8
    coords = (np.arange((2 * n + 1) * ss) + 0.5) / ss - (n + 0.5)
    yy, xx = np.meshgrid(coords, coords, indexing="ij")
    inside = (xx * xx + yy * yy <= radius * radius).astype(np.float32)
    k = inside.reshape(2 * n + 1, ss, 2 * n + 1, ss).mean(axis=(1, 3))
    return k / k.sum()


def line_kernel(length, angle_deg):
    """Normalised line of `length` px at `angle_deg` (a linear motion during the exposure)."""
    n = int(math.ceil(length / 2.0)) + 1
    k = np.zeros((2 * n + 1, 2 * n + 1), np.float32)
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    for t in np.linspace(-length / 2.0, length / 2.0, int(4 * math.ceil(length)) + 1):
        x, y = n + t * c, n + t * s
        x0, y0 = int(math.floor(x)), int(math.floor(y))
        fx, fy = x - x0, y - y0
        k[y0, x0] += (1 - fx) * (1 - fy)
        k[y0, x0 + 1] += fx * (1 - fy)
        k[y0 + 1, x0] += (1 - fx) * fy
        k[y0 + 1, x0 + 1] += fx * fy
    return k / k.sum()


# Standard normal numbers for the sensor noise, drawn once per process from a fixed seed: a frame
# takes a slice at an offset from its noise seed, flipping signs by a second draw. Drawing a million
# normals per frame would cost 22 ms, more than the render; a slice costs well under one.
_NOISE_LEN = 1 << 22
_NOISE = []


def gaussian_noise(shape, seed):
    """float32 standard normal noise of `shape`, a function of `seed` alone."""
    if not _NOISE:
        _NOISE.append(np.random.default_rng(20261123).standard_normal(_NOISE_LEN, dtype=np.float32))
    table = _NOISE[0]
    n = int(np.prod(shape))
    if n > _NOISE_LEN // 2:
        return np.random.default_rng(seed).standard_normal(shape, dtype=np.float32)
    rng = np.random.default_rng(seed)
    start = int(rng.integers(0, _NOISE_LEN - n))
    out = table[start:start + n].reshape(shape)
    return -out if rng.uniform() < 0.5 else out


_RR = {}  # (w, h, u0, v0) -> rr^2 map


def _falloff(w, h, principal, v):
    """float32 [H, W, 3] gain 1 - v rr^2 of the vignetting."""
    key = (w, h, float(principal[0]), float(principal[1]))
    rr = _RR.get(key)
    if rr is None:
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        u0, v0 = principal
        rr = ((xx + 0.5 - u0) ** 2 + (yy + 0.5 - v0) ** 2) / ((w / 2.0) ** 2 + (h / 2.0) ** 2)
        if len(_RR) > 8:
            _RR.clear()
        rr = _RR[key] = cv2.cvtColor(rr.astype(np.float32), cv2.COLOR_GRAY2RGB)
    return 1.0 - v * rr


def finish(rgba, background, im, principal):
    """uint8 RGB frame from the rendered RGBA (premultiplied, alpha 0 on the background), the
    background (float32 0..255) and image draw `im`. Works in float32 on the 0..255 scale."""
    # Premultiplied: the render's background is black with alpha 0, so its colours (and those the lens
    # remap blends at the outline) already carry their alpha.
    inv = cv2.cvtColor(255 - rgba[..., 3], cv2.COLOR_GRAY2RGB)
    x = cv2.multiply(background, inv, scale=1.0 / 255.0, dtype=cv2.CV_32F)
    x += cv2.cvtColor(rgba, cv2.COLOR_RGBA2RGB).astype(np.float32)  # (cv2.add of mixed types: 8x slower)
    if im["defocus_px"] > 0.3:
        x = cv2.filter2D(x, -1, disc_kernel(im["defocus_px"]), borderType=cv2.BORDER_REFLECT)
    if im["motion_px"] > 0.5:
        x = cv2.filter2D(x, -1, line_kernel(im["motion_px"], im["motion_deg"]), borderType=cv2.BORDER_REFLECT)
    h, w = x.shape[:2]
    gain = im["exposure"]
    if im["vignetting"] > 0:
        x = cv2.multiply(x, _falloff(w, h, principal, im["vignetting"]), scale=gain)
    elif gain != 1.0:
        x *= gain
    if im["read_noise"] > 0 or im["shot_noise"] > 0:
        var = np.clip(x, 0.0, 255.0)
        var *= im["shot_noise"] ** 2 / 255.0
        var += im["read_noise"] ** 2
        x += cv2.sqrt(var) * gaussian_noise(x.shape, im["noise_seed"])
    np.clip(x, 0.0, 255.0, out=x)
    if im["gamma"] != 1.0:
        x *= 1.0 / 255.0
        x **= 1.0 / im["gamma"]
        x *= 255.0
    out = cv2.convertScaleAbs(x)  # x >= 0 here: rounds to nearest and saturates to 8 bits in one pass
    if im["jpeg_quality"] is not None:
        ok, buf = cv2.imencode(".jpg", cv2.cvtColor(out, cv2.COLOR_RGB2BGR),
                               [cv2.IMWRITE_JPEG_QUALITY, int(im["jpeg_quality"])])
        out = cv2.cvtColor(cv2.imdecode(buf, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    return out
