"""The pinhole camera of conventions.md, from a JSON file (docs/interfaces.md).

A camera file holds any of the keys of the reference camera; missing keys take
the reference values, unknown keys and bad values are errors that name the
file and the key.
"""
import json
import math
from dataclasses import asdict, dataclass

import numpy as np

# The reference camera of the benchmarks (conventions.md, "Camera").
REFERENCE = {"width": 640, "height": 512, "focal_mm": 16.0, "pixel_mm": 0.0096,
             "distance_mm": 250.0, "sphere_diameter_mm": 40.0}

_INT_KEYS = ("width", "height")
_FLOAT_KEYS = ("focal_mm", "pixel_mm", "distance_mm", "sphere_diameter_mm")


class CameraError(ValueError):
    """A camera file or value that cannot be used; the message names the file and key."""


@dataclass(frozen=True)
class Camera:
    """Pinhole camera: W x H pixels of pitch pixel_mm, focal length focal_mm,
    on +Z at distance_mm from the sphere centre, looking at the origin."""
    width: int = REFERENCE["width"]
    height: int = REFERENCE["height"]
    focal_mm: float = REFERENCE["focal_mm"]
    pixel_mm: float = REFERENCE["pixel_mm"]
    distance_mm: float = REFERENCE["distance_mm"]
    sphere_diameter_mm: float = REFERENCE["sphere_diameter_mm"]

    @property
    def focal_px(self):
        """Focal length in pixels, f / p."""
        return self.focal_mm / self.pixel_mm

    @property
    def radius_mm(self):
        return self.sphere_diameter_mm / 2.0

    @property
    def view_angle_deg(self):
        """Vertical field of view in degrees (what vtkCamera.SetViewAngle takes)."""
        return math.degrees(2.0 * math.atan(self.height * self.pixel_mm / (2.0 * self.focal_mm)))

    def project(self, world_mm):
        """Continuous pixel coordinates (u, v) [N, 2] of world points [N, 3] in mm."""
        p = np.atleast_2d(np.asarray(world_mm, dtype=float))
        depth = self.distance_mm - p[:, 2]
        u = self.width / 2.0 + self.focal_px * p[:, 0] / depth
        v = self.height / 2.0 - self.focal_px * p[:, 1] / depth
        return np.stack([u, v], axis=1)

    def to_dict(self):
        return asdict(self)


def camera_from_dict(values, source="camera"):
    """Camera from a dict of the camera file's keys; `source` names where they came from in errors."""
    if not isinstance(values, dict):
        raise CameraError(f"{source}: expected a JSON object with keys {', '.join(REFERENCE)}")
    merged = dict(REFERENCE)
    for key, value in values.items():
        if key not in REFERENCE:
            raise CameraError(f"{source}: unknown key {key!r} (valid keys: {', '.join(REFERENCE)})")
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise CameraError(f"{source}: key {key!r} must be a number, got {value!r}")
        if not math.isfinite(value) or value <= 0:
            raise CameraError(f"{source}: key {key!r} must be a positive finite number, got {value!r}")
        if key in _INT_KEYS:
            if float(value) != int(value):
                raise CameraError(f"{source}: key {key!r} must be a whole number of pixels, got {value!r}")
            value = int(value)
        else:
            value = float(value)
        merged[key] = value
    cam = Camera(**merged)
    if cam.distance_mm <= cam.radius_mm * 1.05:
        raise CameraError(f"{source}: key 'distance_mm' ({cam.distance_mm}) must exceed the sphere radius "
                          f"({cam.radius_mm}) with room to spare: the camera would sit inside the sphere")
    if cam.width > 16384 or cam.height > 16384:
        raise CameraError(f"{source}: image size {cam.width} x {cam.height} is larger than 16384 pixels")
    return cam


def read_json(path, what, error=ValueError):
    """Parsed JSON of file `path`; `error` names the file and says what it should be (`what`)."""
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except OSError as e:
        raise error(f"{path}: cannot read {what}: {e.strerror}") from None
    except json.JSONDecodeError as e:
        raise error(f"{path}: not valid JSON: {e}") from None


def load_camera(path=None):
    """Camera from a JSON file (None: the reference camera). CameraError names the file and key."""
    if path is None:
        return Camera()
    return camera_from_dict(read_json(path, "camera file", CameraError), source=str(path))
