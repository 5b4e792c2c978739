"""Domain randomisation for sim-to-real: per-frame lights, intrinsics, background and image effects.

Everything is off by default (a Randomization() changes nothing). Each frame
draws its own values from its own generator (the dataset seeds it from the
seed and the pose index), so a frame never depends on the frames before it.

Order of effects on a frame: lights, background, principal-point offset and
focal-length scale are given to the renderer; then, on the rendered image,
exposure (gain) and gamma, Gaussian blur, Gaussian sensor noise; rounding to
8 bits last.
"""
from dataclasses import asdict, dataclass, fields, replace

import cv2
import numpy as np

from sim.render import Light


@dataclass(frozen=True)
class Randomization:
    """Ranges of the per-frame disturbances; the defaults disturb nothing."""
    light_jitter_deg: float = 0.0        # each light's direction tilted by up to this angle
    light_intensity: tuple = (1.0, 1.0)  # each light's intensity times U(lo, hi)
    background_jitter: int = 0           # each background channel + U{-n..n}, clipped to 0..255
    offset_px: float = 0.0               # principal point moved by U(-o, o) px in u and in v
    scale: float = 0.0                   # focal length times U(1 - s, 1 + s)
    exposure: tuple = (1.0, 1.0)         # image gain U(lo, hi)
    gamma: tuple = (1.0, 1.0)            # out = in ** (1 / gamma), gamma U(lo, hi)
    blur: float = 0.0                    # Gaussian blur, sigma U(0, b) px
    noise: float = 0.0                   # Gaussian noise, sigma U(0, n) in 8-bit levels

    @property
    def enabled(self):
        return self != Randomization()

    def to_dict(self):
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}


# What `--randomize` turns on (each can still be set on its own flag).
PRESET = Randomization(light_jitter_deg=25.0, light_intensity=(0.7, 1.2), background_jitter=20,
                       offset_px=8.0, scale=0.05, exposure=(0.8, 1.2), gamma=(0.85, 1.15),
                       blur=1.0, noise=4.0)

FIELDS = tuple(f.name for f in fields(Randomization))


def check(rz):
    """ValueError naming the setting when a range is impossible."""
    for name in ("light_intensity", "exposure", "gamma"):
        lo, hi = getattr(rz, name)
        if not (0 < lo <= hi):
            raise ValueError(f"randomisation {name}: need 0 < low <= high, got {lo}, {hi}")
    for name in ("light_jitter_deg", "background_jitter", "offset_px", "blur", "noise"):
        if getattr(rz, name) < 0:
            raise ValueError(f"randomisation {name}: must be >= 0, got {getattr(rz, name)}")
    if not 0 <= rz.scale < 0.5:
        raise ValueError(f"randomisation scale: must be in [0, 0.5), got {rz.scale}")
    if not 0 <= rz.light_jitter_deg <= 90:
        raise ValueError(f"randomisation light_jitter_deg: must be in [0, 90], got {rz.light_jitter_deg}")
    return rz


def with_preset(rz, given):
    """`rz` with every field not in `given` (names set explicitly) taken from PRESET."""
    return replace(rz, **{k: getattr(PRESET, k) for k in FIELDS if k not in given})


@dataclass(frozen=True)
class FrameParams:
    """The disturbances drawn for one frame."""
    lights: tuple
    background: tuple
    offset_px: tuple
    scale: float
    gain: float
    gamma: float
    blur_sigma: float
    noise_sigma: float


def _tilt(direction, max_deg, rng):
    """`direction` tilted by an angle up to max_deg (uniform over the spherical cap) toward a random side."""
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    if max_deg <= 0:
        return tuple(d)
    cos_t = rng.uniform(np.cos(np.radians(max_deg)), 1.0)
    sin_t = np.sqrt(max(0.0, 1.0 - cos_t * cos_t))
    a = rng.uniform(0.0, 2.0 * np.pi)
    helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(d, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    return tuple(cos_t * d + sin_t * (np.cos(a) * e1 + np.sin(a) * e2))


def sample(rz, rng, lights, background):
    """FrameParams for one frame from generator `rng` (always draws the same count, in the same order)."""
    new_lights = []
    for light in lights:
        direction = _tilt(light.direction, rz.light_jitter_deg, rng)
        k = rng.uniform(*rz.light_intensity)
        new_lights.append(Light(direction, light.intensity * k, light.color))
    jitter = rng.integers(-rz.background_jitter, rz.background_jitter + 1, size=3)
    bg = tuple(int(np.clip(c + j, 0, 255)) for c, j in zip(background, jitter))
    offset = tuple(float(v) for v in rng.uniform(-rz.offset_px, rz.offset_px, size=2))
    scale = float(rng.uniform(1.0 - rz.scale, 1.0 + rz.scale))
    gain = float(rng.uniform(*rz.exposure))
    gamma = float(rng.uniform(*rz.gamma))
    blur = float(rng.uniform(0.0, rz.blur))
    noise = float(rng.uniform(0.0, rz.noise))
    return FrameParams(tuple(new_lights), bg, offset, scale, gain, gamma, blur, noise)


def apply_image_effects(img, fp, rng):
    """Exposure, gamma, blur and noise of FrameParams `fp` on an RGB uint8 image; returns uint8."""
    if fp.gain == 1.0 and fp.gamma == 1.0 and fp.blur_sigma == 0.0 and fp.noise_sigma == 0.0:
        return img
    x = img.astype(np.float32) / 255.0
    if fp.gain != 1.0 or fp.gamma != 1.0:
        x = np.clip(x * fp.gain, 0.0, 1.0) ** (1.0 / fp.gamma)
    if fp.blur_sigma > 0.0:
        x = cv2.GaussianBlur(x, (0, 0), fp.blur_sigma)
    x *= 255.0
    if fp.noise_sigma > 0.0:
        x += rng.normal(0.0, fp.noise_sigma, size=x.shape).astype(np.float32)
    return np.clip(np.rint(x), 0, 255).astype(np.uint8)


def render_frame(renderer, pose, rz, rng):
    """One disturbed frame (RGB uint8) of `renderer` at `pose` with randomisation `rz` drawn from `rng`."""
    if not rz.enabled:
        return renderer.render(pose)
    fp = sample(rz, rng, renderer.lights, renderer.background)
    img = renderer.render(pose, lights=fp.lights, background=fp.background,
                          offset_px=fp.offset_px, scale=fp.scale)
    return apply_image_effects(img, fp, rng)
