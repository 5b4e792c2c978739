"""Scene files: what a rig looks like, and the per-frame draw within the file's ranges (docs/sim.md).

A scene file is JSON. Every numeric setting is a number (fixed) or [low, high]
(uniform per frame); a colour is [r, g, b] (fixed, 0-255) or
{"hue": deg, "saturation": s, "value": v} with each a number or a range; a
choice is {"name": weight, ...}. A key left out takes the plain renderer's
value (no mount, flat (64, 64, 70) background, the default lights and
material, no image effects), so a file describing one real rig names only
what it has, and a training scene names every range.

`draw(scene, rng)` turns the ranges into one frame's values: a JSON-able dict
that the scene renderer follows exactly and that the dataset writes to
truth.jsonl, so a frame depends only on its generator.
"""
import colorsys
import hashlib
import itertools
import math
import os
from dataclasses import dataclass, field, replace

import numpy as np

from sim.camera import Camera, CameraError, camera_from_dict, check_distortion, read_json

FORMAT = "spherepose-scene-1"
# The scene renderer's version, in every scene dataset's record: bump it when the same draw would
# give other pixels (a resume then refuses a folder rendered by the older code, naming this key).
RENDERER = 1
PHOTO_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")

MOUNT_KINDS = ("none", "post", "cup", "fork")
BACKGROUND_KINDS = ("flat", "gradient", "clutter", "photo")

# The plain renderer's values (sim/render.py), what a key left out means.
PLAIN_MATERIAL = {"ambient": 0.45, "diffuse": 0.6, "specular": 0.08, "specular_power": 20.0}
PLAIN_BACKGROUND = (64, 64, 70)


class SceneError(ValueError):
    """A scene file that cannot be used; the message names the file and the key."""


# ---- value specifications ----------------------------------------------------

def _is_num(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


class _Reader:
    """Reads one JSON object of the scene file, naming `file: key 'a.b'` in every error."""

    def __init__(self, source, obj, path, keys):
        self.source, self.path = source, path
        if not isinstance(obj, dict):
            if not path:
                raise SceneError(f"{source}: expected a JSON object (a scene: docs/sim.md, 'Rig scenes')")
            raise SceneError(f"{source}: key {path!r}: expected a JSON object")
        unknown = sorted(set(obj) - set(keys))
        if unknown:
            where = f"key {path + '.' + unknown[0]!r}" if path else f"key {unknown[0]!r}"
            raise SceneError(f"{source}: unknown {where} (valid keys{' of ' + repr(path) if path else ''}: "
                             f"{', '.join(keys)})")
        self.obj = obj

    def key(self, name):
        return f"{self.path}.{name}" if self.path else name

    def fail(self, name, why):
        raise SceneError(f"{self.source}: key {self.key(name)!r}: {why}")

    def range(self, name, default, lo=-math.inf, hi=math.inf):
        """(low, high) from a number or [low, high], each within [lo, hi]."""
        v = self.obj.get(name, default)
        if _is_num(v):
            v = [v, v]
        if not (isinstance(v, (list, tuple)) and len(v) == 2 and all(_is_num(x) for x in v)):
            self.fail(name, f"expected a number or [low, high], got {v!r}")
        a, b = float(v[0]), float(v[1])
        if a > b:
            self.fail(name, f"low {a} is above high {b}")
        if a < lo or b > hi:
            self.fail(name, f"must lie within [{lo}, {hi}], got {v!r}")
        return (a, b)

    def int_range(self, name, default, lo, hi):
        a, b = self.range(name, default, lo, hi)
        if a != int(a) or b != int(b):
            self.fail(name, f"expected whole numbers, got {self.obj.get(name)!r}")
        return (int(a), int(b))

    def color(self, name, default):
        v = self.obj.get(name, default)
        if isinstance(v, (list, tuple)):
            if len(v) != 3 or not all(_is_num(x) and 0 <= x <= 255 for x in v):
                self.fail(name, f"expected [r, g, b] within 0..255 or {{\"hue\", \"saturation\", \"value\"}}, "
                                f"got {v!r}")
            return {"rgb": [float(x) for x in v]}
        sub = _Reader(self.source, v, self.key(name), ("hue", "saturation", "value"))
        return {"hue": sub.range("hue", [0, 360], 0, 360), "saturation": sub.range("saturation", 0, 0, 1),
                "value": sub.range("value", 0.5, 0, 1)}

    def choice(self, name, default, kinds):
        v = self.obj.get(name, default)
        if not isinstance(v, dict) or not v:
            self.fail(name, f"expected {{kind: weight, ...}} with kinds among {', '.join(kinds)}, got {v!r}")
        for k, w in v.items():
            if k not in kinds:
                self.fail(name, f"unknown kind {k!r} (kinds: {', '.join(kinds)})")
            if not _is_num(w) or w < 0:
                self.fail(name, f"weight of {k!r} must be a number >= 0, got {w!r}")
        if sum(v.values()) <= 0:
            self.fail(name, "the weights add up to 0")
        return {k: float(w) for k, w in v.items()}


# ---- the parsed scene ----------------------------------------------------------

@dataclass
class Scene:
    """A parsed scene file: the camera and every setting as (low, high) ranges (see docs/sim.md)."""
    source: str
    camera: Camera
    view: dict
    distortion: dict          # None: the camera's own coefficients on every frame
    sphere: dict
    lights: object            # a tuple of sim.render.Light (fixed) or a dict of ranges
    mount: dict
    background: dict
    image: dict
    photos: list = field(default_factory=list)   # absolute paths, sorted
    raw: dict = field(default_factory=dict)      # the file's JSON, for the dataset record

    def settings(self):
        """What a dataset record keeps of the scene (resume must match it): the file's content, the
        resolved camera, the scene renderer's version and the photos' hashes."""
        return {"file": self.raw, "camera": self.camera.to_dict(), "renderer": RENDERER,
                "photos": [[os.path.basename(p), _sha256(p)] for p in self.photos]}


def _sha256(path):
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


TOP_KEYS = ("format", "description", "camera", "view", "distortion", "sphere", "lights", "mount",
            "background", "image")


def load_scene(path, camera_override=None):
    """Scene from a JSON file; SceneError names the file and the key. `camera_override` (a Camera)
    replaces the file's camera."""
    return scene_from_dict(read_json(path, "scene file", SceneError), str(path), camera_override)


def scene_from_dict(obj, source="scene", camera_override=None):
    top = _Reader(source, obj, "", TOP_KEYS)
    fmt = obj.get("format", FORMAT)
    if fmt != FORMAT:
        top.fail("format", f"expected {FORMAT!r}, got {fmt!r}")
    if "description" in obj and not isinstance(obj["description"], str):
        top.fail("description", "expected a string")
    base = os.path.dirname(os.path.abspath(source))
    camera = camera_override or _camera(top, base)

    v = _Reader(source, obj.get("view", {}), "view",
                ("distance_scale", "focal_scale", "offset_u_px", "offset_v_px"))
    view = {"distance_scale": v.range("distance_scale", 1.0, 0.5, 2.0),
            "focal_scale": v.range("focal_scale", 1.0, 0.5, 2.0),
            "offset_u_px": v.range("offset_u_px", 0.0, -camera.width / 2, camera.width / 2),
            "offset_v_px": v.range("offset_v_px", 0.0, -camera.height / 2, camera.height / 2)}
    r_px = camera.radius_px * view["focal_scale"][1] / view["distance_scale"][0]
    if r_px > min(camera.width, camera.height) / 2:
        v.fail("focal_scale", f"at the largest focal scale and nearest distance the sphere ({2 * r_px:.0f} px) "
                              f"does not fit in the {camera.width} x {camera.height} frame")

    distortion = None
    if obj.get("distortion") is not None:
        d = _Reader(source, obj["distortion"], "distortion", ("k1", "k2", "p1", "p2", "k3"))
        distortion = {k: d.range(k, 0.0, -2.0, 2.0) for k in ("k1", "k2", "p1", "p2", "k3")}
        _check_distortion_box(camera, view, distortion, source)

    s = _Reader(source, obj.get("sphere", {}), "sphere", tuple(PLAIN_MATERIAL))
    sphere = {"ambient": s.range("ambient", PLAIN_MATERIAL["ambient"], 0, 1),
              "diffuse": s.range("diffuse", PLAIN_MATERIAL["diffuse"], 0, 2),
              "specular": s.range("specular", PLAIN_MATERIAL["specular"], 0, 2),
              "specular_power": s.range("specular_power", PLAIN_MATERIAL["specular_power"], 1, 500)}

    lights = _lights(top, obj.get("lights"), source)
    mount = _mount(_Reader(source, obj.get("mount", {"kind": {"none": 1}}), "mount", MOUNT_KEYS))
    background, photos = _background(_Reader(source, obj.get("background", {}), "background", BACKGROUND_KEYS),
                                     base)
    i = _Reader(source, obj.get("image", {}), "image", IMAGE_KEYS)
    image = {"exposure": i.range("exposure", 1.0, 0.05, 20),
             "gamma": i.range("gamma", 1.0, 0.2, 5),
             "vignetting": i.range("vignetting", 0.0, 0, 0.9),
             "defocus_px": i.range("defocus_px", 0.0, 0, 20),
             "motion_px": i.range("motion_px", 0.0, 0, 40),
             "read_noise": i.range("read_noise", 0.0, 0, 50),
             "shot_noise": i.range("shot_noise", 0.0, 0, 50),
             "jpeg_quality": (i.int_range("jpeg_quality", 0, 0, 100) if "jpeg_quality" in i.obj else None)}
    if image["jpeg_quality"] is not None and image["jpeg_quality"][0] < 5:
        i.fail("jpeg_quality", "must lie within [5, 100] (leave the key out for no JPEG)")
    return Scene(source, camera, view, distortion, sphere, lights, mount, background, image, photos, obj)


def _camera(top, base):
    c = top.obj.get("camera", {})
    if isinstance(c, str):
        path = c if os.path.isabs(c) else os.path.join(base, c)
        try:
            return camera_from_dict(read_json(path, "camera file", CameraError), source=path)
        except CameraError as e:
            raise SceneError(f"{top.source}: key 'camera': {e}") from None
    try:
        return camera_from_dict(c, source=f"{top.source}: key 'camera'")
    except CameraError as e:
        raise SceneError(str(e)) from None


def _check_distortion_box(camera, view, distortion, source):
    """Every corner of the coefficients' box must be a usable lens for this camera."""
    keys = ("k1", "k2", "p1", "p2", "k3")
    for combo in itertools.product(*(distortion[k] for k in keys)):
        cam = replace(camera, distortion=tuple(combo), focal_mm=camera.focal_mm * view["focal_scale"][0])
        try:
            check_distortion(cam, f"{source}: key 'distortion' at {dict(zip(keys, combo))}")
        except CameraError as e:
            raise SceneError(str(e)) from None


LIGHT_KEYS = ("count", "angle_deg", "azimuth_deg", "intensity", "temperature_k")


def _lights(top, value, source):
    from sim.render import DEFAULT_LIGHTS, lights_from_json
    if value is None:
        return DEFAULT_LIGHTS
    if isinstance(value, list):
        try:
            return lights_from_json(value, source=f"{source}: key 'lights'")
        except ValueError as e:
            raise SceneError(str(e)) from None
    r = _Reader(source, value, "lights", LIGHT_KEYS)
    return {"count": r.int_range("count", 2, 1, 8),
            "angle_deg": r.range("angle_deg", [0, 60], 0, 180),
            "azimuth_deg": r.range("azimuth_deg", [0, 360], -360, 720),
            "intensity": r.range("intensity", [0.3, 0.7], 0, 5),
            "temperature_k": r.range("temperature_k", 6500, 1000, 40000)}


MOUNT_KEYS = ("kind", "direction_deg", "tilt_deg", "post_radius_mm", "cup_radius_frac", "cup_height_frac",
              "fork_spread_frac", "fork_roll_deg", "length_mm", "color", "ambient", "diffuse", "specular",
              "specular_power")


def _mount(r):
    kind = r.choice("kind", {"post": 1}, MOUNT_KINDS)
    return {"kind": kind,
            "direction_deg": r.range("direction_deg", 0.0, -360, 360),
            "tilt_deg": r.range("tilt_deg", 0.0, -45, 45),
            "post_radius_mm": r.range("post_radius_mm", 4.0, 0.1, 1000),
            "cup_radius_frac": r.range("cup_radius_frac", 0.7, 0.2, 0.95),
            "cup_height_frac": r.range("cup_height_frac", 0.5, 0.05, 3),
            "fork_spread_frac": r.range("fork_spread_frac", 0.7, 0.3, 0.95),
            "fork_roll_deg": r.range("fork_roll_deg", 0.0, -60, 60),
            "length_mm": r.range("length_mm", 150.0, 1, 10000),
            "color": r.color("color", [150, 150, 155]),
            "ambient": r.range("ambient", 0.3, 0, 1),
            "diffuse": r.range("diffuse", 0.7, 0, 2),
            "specular": r.range("specular", 0.2, 0, 2),
            "specular_power": r.range("specular_power", 20, 1, 500)}


BACKGROUND_KEYS = ("kind", "color", "color2", "shapes", "shape_size_frac", "shape_color", "blur_px",
                   "photos", "photo_gain", "seed")


def _background(r, base):
    bg = {"kind": r.choice("kind", {"flat": 1}, BACKGROUND_KINDS),
          "color": r.color("color", list(PLAIN_BACKGROUND)),
          "color2": r.color("color2", {"hue": [0, 360], "saturation": [0, 0.5], "value": [0, 1]}),
          "shapes": r.int_range("shapes", [5, 30], 0, 500),
          "shape_size_frac": r.range("shape_size_frac", [0.03, 0.4], 0.005, 2),
          "shape_color": r.color("shape_color", {"hue": [0, 360], "saturation": [0, 0.8], "value": [0, 1]}),
          "blur_px": r.range("blur_px", 0.0, 0, 30),
          "photo_gain": r.range("photo_gain", 1.0, 0.05, 5),
          "seed": None}
    if "seed" in r.obj:
        seed = r.obj["seed"]
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            r.fail("seed", f"expected a whole number >= 0 (one fixed background for every frame), got {seed!r}")
        bg["seed"] = seed
    photos = []
    folder = r.obj.get("photos")
    if folder is not None:
        if not isinstance(folder, str):
            r.fail("photos", f"expected a folder name, got {folder!r}")
        path = folder if os.path.isabs(folder) else os.path.join(base, folder)
        if not os.path.isdir(path):
            r.fail("photos", f"folder {path} not found")
        photos = sorted(os.path.join(path, n) for n in os.listdir(path)
                        if n.lower().endswith(PHOTO_EXTENSIONS) and not n.startswith("."))
        if not photos:
            r.fail("photos", f"folder {path} holds no images ({', '.join(PHOTO_EXTENSIONS)})")
        for p in photos:  # a header check now, so that a broken file fails before any rendering
            try:
                from PIL import Image
                with Image.open(p) as im:
                    im.verify()
            except Exception as e:  # PIL raises many kinds for a broken file
                r.fail("photos", f"{p}: not a readable image ({e})")
    if bg["kind"].get("photo", 0) > 0 and not photos:
        r.fail("kind", "kind 'photo' needs a 'photos' folder")
    return bg, photos


IMAGE_KEYS = ("exposure", "gamma", "vignetting", "defocus_px", "motion_px", "read_noise", "shot_noise",
              "jpeg_quality")


# ---- the per-frame draw -------------------------------------------------------------

def _u(rng, rg):
    return float(rng.uniform(rg[0], rg[1]))


def _pick(rng, weights):
    kinds = sorted(weights)
    p = np.array([weights[k] for k in kinds], float)
    return kinds[int(rng.choice(len(kinds), p=p / p.sum()))]


def _color(rng, spec):
    """[r, g, b] floats 0-255 of a colour spec."""
    if "rgb" in spec:
        return list(spec["rgb"])
    h, s, v = _u(rng, spec["hue"]) / 360.0 % 1.0, _u(rng, spec["saturation"]), _u(rng, spec["value"])
    return [round(255.0 * c, 3) for c in colorsys.hsv_to_rgb(h, s, v)]


def kelvin_rgb(t):
    """Colour (r, g, b) in 0..1 (max channel 1) of a black body at t kelvin (Tanner Helland's fit)."""
    t = t / 100.0
    r = 1.0 if t <= 66 else min(1.0, 1.29293618606 * (t - 60) ** -0.1332047592)
    g = (0.39008157876 * math.log(t) - 0.63184144378) if t <= 66 else 1.12989086089 * (t - 60) ** -0.0755148492
    b = 1.0 if t >= 66 else (0.0 if t <= 19 else 0.54320678911 * math.log(t - 10) - 1.19625408914)
    rgb = [min(1.0, max(0.0, c)) for c in (r, g, b)]
    m = max(rgb)
    return [round(c / m, 6) for c in rgb]


def _draw_lights(rng, spec):
    if not isinstance(spec, dict):
        return [{"direction": list(l.direction), "intensity": l.intensity, "color": list(l.color)} for l in spec]
    out = []
    for _ in range(int(rng.integers(spec["count"][0], spec["count"][1] + 1))):
        a = math.radians(_u(rng, spec["angle_deg"]))
        az = math.radians(_u(rng, spec["azimuth_deg"]))
        direction = [round(math.sin(a) * math.cos(az), 6), round(math.sin(a) * math.sin(az), 6),
                     round(math.cos(a), 6)]
        out.append({"direction": direction, "intensity": round(_u(rng, spec["intensity"]), 6),
                    "color": kelvin_rgb(_u(rng, spec["temperature_k"]))})
    return out


def draw(scene, rng):
    """One frame's values (a JSON-able dict) drawn from numpy Generator `rng` within the scene's ranges."""
    cam = scene.camera
    v = scene.view
    f_px = cam.focal_px * _u(rng, v["focal_scale"])
    dist_mm = cam.distance_mm * _u(rng, v["distance_scale"])
    offset = [_u(rng, v["offset_u_px"]), _u(rng, v["offset_v_px"])]
    if scene.distortion is None:
        coeffs = list(cam.distortion)
    else:
        coeffs = [_u(rng, scene.distortion[k]) for k in ("k1", "k2", "p1", "p2", "k3")]
    sphere = {k: _u(rng, rg) for k, rg in scene.sphere.items()}
    lights = _draw_lights(rng, scene.lights)

    m = scene.mount
    kind = _pick(rng, m["kind"])
    mount = {"kind": kind}
    if kind != "none":
        mount.update({k: _u(rng, m[k]) for k in ("direction_deg", "tilt_deg", "post_radius_mm", "cup_radius_frac",
                                                  "cup_height_frac", "fork_spread_frac", "fork_roll_deg",
                                                  "length_mm", "ambient", "diffuse", "specular",
                                                  "specular_power")})
        mount["color"] = _color(rng, m["color"])

    b = scene.background
    bkind = _pick(rng, b["kind"])
    background = {"kind": bkind, "color": _color(rng, b["color"]), "color2": _color(rng, b["color2"]),
                  "blur_px": _u(rng, b["blur_px"]), "seed": int(rng.integers(0, 2 ** 62))}
    if b["seed"] is not None:  # a rig's fixed background: the same layout on every frame
        background["seed"] = b["seed"]
    if bkind == "photo":
        background["photo"] = os.path.basename(scene.photos[int(rng.integers(0, len(scene.photos)))])
        background["photo_gain"] = _u(rng, b["photo_gain"])

    im = scene.image
    image = {k: _u(rng, im[k]) for k in ("exposure", "gamma", "vignetting", "defocus_px", "motion_px",
                                          "read_noise", "shot_noise")}
    image["motion_deg"] = _u(rng, (0.0, 180.0))
    image["jpeg_quality"] = (None if im["jpeg_quality"] is None
                             else int(rng.integers(im["jpeg_quality"][0], im["jpeg_quality"][1] + 1)))
    image["noise_seed"] = int(rng.integers(0, 2 ** 62))

    r_px = f_px * cam.radius_mm / math.sqrt(dist_mm ** 2 - cam.radius_mm ** 2)
    u0, v0 = cam.principal
    return {
        # The frame's camera; with width, height, pixel pitch and sphere diameter a reader can rebuild
        # a camera file for it (focal_mm = focal_px * pixel_mm): sim.camera.from_truth, tested in
        # tests/training/test_truth_camera.py.
        "camera": {"focal_px": f_px, "principal_px": [u0, v0], "distortion": coeffs, "distance_mm": dist_mm,
                   "width": cam.width, "height": cam.height, "pixel_mm": cam.pixel_mm,
                   "sphere_diameter_mm": cam.sphere_diameter_mm},
        "offset_px": offset,
        "circle": [u0 + offset[0], v0 + offset[1], r_px],
        "sphere": sphere, "lights": lights, "mount": mount, "background": background, "image": image,
    }


def margin_for(scene):
    """Pixels the pinhole render needs beyond the frame for the widest distortion the scene draws."""
    from sim.lens import margin_px
    cam = scene.camera
    boxes = ([[c] for c in cam.distortion] if scene.distortion is None
             else [scene.distortion[k] for k in ("k1", "k2", "p1", "p2", "k3")])
    if not any(any(b) for b in boxes):
        return 0
    f_lo = cam.focal_px * scene.view["focal_scale"][0]
    return max(margin_px(cam.width, cam.height, f_lo, cam.principal, combo)
               for combo in itertools.product(*boxes))
