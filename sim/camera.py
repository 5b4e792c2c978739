"""The pinhole camera of conventions.md, from a JSON file (docs/interfaces.md).

A camera file holds any of the keys of the reference camera; missing keys take
the reference values, unknown keys and bad values are errors that name the
file and the key.

Two optional keys carry a real camera's OpenCV calibration: "principal_px"
[u0, v0] in the conventions' continuous pixel coordinates (default the image
centre) and "distortion" [k1, k2, p1, p2, k3] (OpenCV's model, default none).
OpenCV puts pixel centres at integers, the conventions at half-integers, so
OpenCV's camera matrix has cx = u0 - 0.5, cy = v0 - 0.5 (`opencv_matrix`).
"""
import json
import math
from dataclasses import asdict, dataclass

import numpy as np

# The reference camera of the benchmarks (conventions.md, "Camera"): the `camera` of
# tests/data/conventions_vectors.json (tests/sim/test_reference_camera.py holds it to that file).
REFERENCE = {"width": 640, "height": 512, "focal_mm": 16.0, "pixel_mm": 0.0096,
             "distance_mm": 250.0, "sphere_diameter_mm": 40.0}

_INT_KEYS = ("width", "height")
_FLOAT_KEYS = ("focal_mm", "pixel_mm", "distance_mm", "sphere_diameter_mm")
# Optional calibration keys (lists); absent means the ideal pinhole camera.
_LIST_KEYS = {"principal_px": 2, "distortion": 5}
VALID_KEYS = tuple(REFERENCE) + tuple(_LIST_KEYS)
NO_DISTORTION = (0.0, 0.0, 0.0, 0.0, 0.0)


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
    principal_px: tuple = None          # (u0, v0) continuous pixels; None: (W/2, H/2)
    distortion: tuple = NO_DISTORTION   # OpenCV (k1, k2, p1, p2, k3)

    @property
    def principal(self):
        """Principal point (u0, v0) in continuous pixel coordinates."""
        if self.principal_px is None:
            return (self.width / 2.0, self.height / 2.0)
        return tuple(self.principal_px)

    @property
    def distorted(self):
        return any(c != 0.0 for c in self.distortion)

    def opencv_matrix(self):
        """OpenCV's 3x3 camera matrix (integer pixel centres: c = u0 - 0.5), fx = fy = f / p."""
        u0, v0 = self.principal
        f = self.focal_px
        return np.array([[f, 0.0, u0 - 0.5], [0.0, f, v0 - 0.5], [0.0, 0.0, 1.0]])

    @property
    def radius_px(self):
        """Radius of the sphere's (undistorted) outline in pixels: f R / sqrt(D^2 - R^2)."""
        r, d = self.radius_mm, self.distance_mm
        return self.focal_px * r / math.sqrt(d * d - r * r)

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
        u0, v0 = self.principal
        u = u0 + self.focal_px * p[:, 0] / depth
        v = v0 - self.focal_px * p[:, 1] / depth
        return np.stack([u, v], axis=1)

    def to_dict(self):
        """The camera file's keys; the calibration keys only when set (older records stay equal)."""
        d = asdict(self)
        if self.principal_px is None:
            del d["principal_px"]
        else:
            d["principal_px"] = list(self.principal_px)
        if not self.distorted:
            del d["distortion"]
        else:
            d["distortion"] = list(self.distortion)
        return d


def camera_from_dict(values, source="camera"):
    """Camera from a dict of the camera file's keys; `source` names where they came from in errors."""
    if not isinstance(values, dict):
        raise CameraError(f"{source}: expected a JSON object with keys {', '.join(VALID_KEYS)}")
    merged = dict(REFERENCE)
    for key, value in values.items():
        if key not in VALID_KEYS:
            raise CameraError(f"{source}: unknown key {key!r} (valid keys: {', '.join(VALID_KEYS)})")
        if key in _LIST_KEYS:
            merged[key] = _number_list(value, _LIST_KEYS[key], key, source)
            continue
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
    if "distortion" in merged:
        check_distortion(cam, source)
    if cam.distance_mm <= cam.radius_mm * 1.05:
        raise CameraError(f"{source}: key 'distance_mm' ({cam.distance_mm}) must exceed the sphere radius "
                          f"({cam.radius_mm}) with room to spare: the camera would sit inside the sphere")
    if cam.width > 16384 or cam.height > 16384:
        raise CameraError(f"{source}: image size {cam.width} x {cam.height} is larger than 16384 pixels")
    return cam


def _number_list(value, n, key, source):
    """A list of n finite numbers (floats); CameraError names the key otherwise."""
    if (not isinstance(value, list) or len(value) != n
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                       for v in value)):
        raise CameraError(f"{source}: key {key!r} must be a list of {n} finite numbers, got {value!r}")
    return tuple(float(v) for v in value)


def check_distortion(cam, source):
    """Refuse coefficients under which the image is not one-to-one (the lens model folds over).

    Along the frame's diagonal the distorted radius r (1 + k1 r^2 + k2 r^4 + k3 r^6) must grow
    with r; the tangential terms are checked to stay below 10 % of r there.
    """
    k1, k2, p1, p2, k3 = cam.distortion
    u0, v0 = cam.principal
    corners = np.array([[0, 0], [cam.width, 0], [0, cam.height], [cam.width, cam.height]], float)
    r_max = float(np.max(np.hypot(corners[:, 0] - u0, corners[:, 1] - v0))) / cam.focal_px * 1.1
    r = np.linspace(0.0, r_max, 200)
    rd = r * (1 + k1 * r ** 2 + k2 * r ** 4 + k3 * r ** 6)
    if np.any(np.diff(rd) <= 0):
        raise CameraError(f"{source}: key 'distortion': the radial terms fold the image over within the "
                          f"frame (distorted radius not increasing); not a usable calibration")
    if r_max > 0 and 2.0 * math.hypot(p1, p2) * r_max > 0.1:
        raise CameraError(f"{source}: key 'distortion': tangential terms p1, p2 move the frame's corners "
                          f"by more than 10 %; not a usable calibration")


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


def from_truth(drawn):
    """Camera-file keys of a frame's camera as a rig scene's truth.jsonl line gives it ("scene":
    {"camera": {"focal_px", "principal_px", "distortion", "distance_mm", ...}}, written by
    sim/scene.draw): the focal length in pixels becomes focal_mm at the reference pixel pitch (only
    their ratio matters). Width and height are left to the reader, who has the frame. KeyError,
    TypeError or ValueError for a record without a usable focal_px."""
    return {"focal_mm": float(drawn["focal_px"]) * REFERENCE["pixel_mm"], "pixel_mm": REFERENCE["pixel_mm"],
            "distance_mm": float(drawn.get("distance_mm", REFERENCE["distance_mm"])),
            "sphere_diameter_mm": float(drawn.get("sphere_diameter_mm", REFERENCE["sphere_diameter_mm"])),
            "principal_px": drawn.get("principal_px"), "distortion": drawn.get("distortion")}
