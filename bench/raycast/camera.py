"""The pinhole camera of docs/conventions.md, read from a camera file, and its rays.

Written from the conventions and docs/interfaces.md alone (no code of sim/):
a camera on +Z at distance D looks toward -Z, image right = +X, image up =
+Y, continuous pixel coordinates (pixel (c, r) covers [c, c+1) x [r, r+1)).
A world point (X, Y, Z) lands at

    u = u0 + f/p * X / (D - Z),    v = v0 - f/p * Y / (D - Z)

with (u0, v0) the principal point (default the image centre). A lens with
OpenCV's distortion (k1, k2, p1, p2, k3) moves the normalised pinhole point
(x, y) = ((u - u0), (v - v0)) / (f/p) (y down, as OpenCV's) to

    x' = x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2)
    y' = y (1 + k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 y^2) + 2 p2 x y.

A frame pixel is cast exactly: its distorted point is inverted by Newton's
method (`undistort`) and the ray goes through the pinhole point found.
"""
import json
import math
from dataclasses import dataclass, field, replace

import numpy as np

REFERENCE = {"width": 640, "height": 512, "focal_mm": 16.0, "pixel_mm": 0.0096,
             "distance_mm": 250.0, "sphere_diameter_mm": 40.0}
NUMBER_KEYS = tuple(REFERENCE)
LIST_KEYS = {"principal_px": 2, "distortion": 5}
NEWTON_STEPS = 8        # |error| < 1e-9 in normalised units after 4-5 steps at the distortions cameras have


class CameraFileError(ValueError):
    """A camera file that cannot be used; the message names the file and the key."""


@dataclass(frozen=True)
class Camera:
    width: int = 640
    height: int = 512
    focal_mm: float = 16.0
    pixel_mm: float = 0.0096
    distance_mm: float = 250.0
    sphere_diameter_mm: float = 40.0
    principal_px: tuple = None                    # (u0, v0); None: (W/2, H/2)
    distortion: tuple = field(default=(0.0,) * 5)  # OpenCV (k1, k2, p1, p2, k3)

    @property
    def f_px(self):
        return self.focal_mm / self.pixel_mm

    @property
    def radius_mm(self):
        return self.sphere_diameter_mm / 2.0

    @property
    def principal(self):
        if self.principal_px is None:
            return (self.width / 2.0, self.height / 2.0)
        return (float(self.principal_px[0]), float(self.principal_px[1]))

    @property
    def distorted(self):
        return any(k != 0.0 for k in self.distortion)

    def radius_px(self, distance_mm=None):
        """Radius of the sphere's undistorted outline: f/p * R / sqrt(D^2 - R^2)."""
        d = self.distance_mm if distance_mm is None else distance_mm
        r = self.radius_mm
        return self.f_px * r / math.sqrt(d * d - r * r)

    def at(self, **changes):
        return replace(self, **changes)

    def to_dict(self):
        d = {k: getattr(self, k) for k in NUMBER_KEYS}
        if self.principal_px is not None:
            d["principal_px"] = list(self.principal_px)
        if self.distorted:
            d["distortion"] = list(self.distortion)
        return d


def camera_from_dict(values, source="camera"):
    if not isinstance(values, dict):
        raise CameraFileError(f"{source}: expected a JSON object")
    kw = {}
    for key, value in values.items():
        if key in NUMBER_KEYS:
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                    or value <= 0:
                raise CameraFileError(f"{source}: key {key!r} must be a positive number, got {value!r}")
            if key in ("width", "height"):
                if value != int(value):
                    raise CameraFileError(f"{source}: key {key!r} must be a whole number, got {value!r}")
                value = int(value)
            kw[key] = value if key in ("width", "height") else float(value)
        elif key in LIST_KEYS:
            n = LIST_KEYS[key]
            if not isinstance(value, list) or len(value) != n or any(
                    isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) for v in value):
                raise CameraFileError(f"{source}: key {key!r} must be a list of {n} numbers, got {value!r}")
            kw[key] = tuple(float(v) for v in value)
        else:
            raise CameraFileError(f"{source}: unknown key {key!r} (valid keys: "
                                  f"{', '.join(NUMBER_KEYS + tuple(LIST_KEYS))})")
    cam = Camera(**kw)
    if cam.distance_mm <= cam.radius_mm * 1.05:
        raise CameraFileError(f"{source}: key 'distance_mm' must exceed the sphere radius {cam.radius_mm} mm")
    return cam


def load_camera(path=None):
    """The camera of a camera file (None: the reference camera)."""
    if path is None:
        return Camera()
    try:
        with open(path, encoding="utf-8") as f:
            values = json.load(f)
    except OSError as e:
        raise CameraFileError(f"{path}: cannot read camera file: {e.strerror}") from None
    except json.JSONDecodeError as e:
        raise CameraFileError(f"{path}: not valid JSON: {e}") from None
    return camera_from_dict(values, source=str(path))


def distort(x, y, k):
    """OpenCV's lens model on normalised pinhole coordinates (y down)."""
    k1, k2, p1, p2, k3 = k
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    return (x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y)


def undistort(xd, yd, k):
    """Pinhole (x, y) whose distorted image is (xd, yd): Newton's method on the 2x2 Jacobian."""
    k1, k2, p1, p2, k3 = k
    x, y = xd.copy(), yd.copy()
    for _ in range(NEWTON_STEPS):
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)   # d radial / d r2
        fx = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - xd
        fy = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - yd
        a = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
        b = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
        c = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
        d = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
        det = a * d - b * c
        x = x - (d * fx - b * fy) / det
        y = y - (a * fy - c * fx) / det
    return x, y


def pixel_rays(cam, u, v, shift=(0.0, 0.0)):
    """Unit world directions of the rays from the camera centre (0, 0, D) through frame points (u, v)
    (continuous pixels). `shift` moves the pinhole image by (du, dv) px before the lens: the sphere
    drawn off-centre while the lens keeps its own principal point (the contract's off-centre sphere)."""
    u0, v0 = cam.principal
    x = (np.asarray(u, np.float64) - u0) / cam.f_px
    y = (np.asarray(v, np.float64) - v0) / cam.f_px
    if cam.distorted:
        x, y = undistort(x, y, cam.distortion)
    x = x - shift[0] / cam.f_px
    y = y - shift[1] / cam.f_px
    d = np.stack([x, -y, -np.ones_like(x)], axis=-1)    # image right = +X, image up = +Y, looking to -Z
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def project(cam, world_mm, distance_mm=None, shift=(0.0, 0.0), lens=True):
    """Frame points (u, v) [N, 2] of world points [N, 3] (with the lens unless lens=False)."""
    p = np.atleast_2d(np.asarray(world_mm, np.float64))
    dist = cam.distance_mm if distance_mm is None else distance_mm
    depth = dist - p[:, 2]
    x = p[:, 0] / depth + shift[0] / cam.f_px
    y = -p[:, 1] / depth + shift[1] / cam.f_px
    if lens and cam.distorted:
        x, y = distort(x, y, cam.distortion)
    u0, v0 = cam.principal
    return np.stack([u0 + cam.f_px * x, v0 + cam.f_px * y], axis=1)
