"""Scene families of the evaluation: what each frame of a family may look like, drawn from a seed.

- `clean`: the reference camera, uniform dark grey backdrop, one light at
  the camera (a headlight) and an ambient term, a faint sheen; nothing else.
- `shifts`: what changes between a render and a camera without a rig:
  1-3 lights from anywhere in front, ambient and exposure levels, sheen
  (specular 0-0.35, exponent 8-80), camera distance +-10 %, the sphere off
  centre (a principal-point shift, anywhere that keeps it in the frame),
  Gaussian blur, read and shot noise, gamma 0.8-1.25; uniform backdrop.
- `rig`: `shifts` plus a rig's scene: a round post under the sphere (dark,
  grey or metal), backdrops of any brightness (flat, gradient, lab
  clutter), vignetting, JPEG.
- `rig-unseen`: `shifts` plus what the training scenes never show: a square
  post of another colour, a fork or a flat holder from the left, right or
  top (hiding up to 15 % of the outline), photo-like smooth noise, stripes,
  checkerboards, near-black and near-white backdrops, defocus (disc) blur,
  vignetting, JPEG. The lens distortion comes from the camera file.
- `edge`: `rig` with the sphere against a frame edge, 2-12 % of its outline
  outside the frame: still to be measured.
- `refuse`: `rig` frames a runtime must refuse (an error or a flag, never a
  confident pose): no sphere on the post (`none`), two spheres (`two`), or
  the sphere cut by a frame edge, 20-45 % of its outline outside (`cut`).
  Their truth line says "expect": "refuse"; `none` has no circle.
- `two-edge` (not one of the evaluation's FAMILIES, rendered only when named):
  `refuse` frames of the kind `two` whose second sphere lies partly beyond
  the left or right frame edge (10-45 % of its outline outside, none beyond
  the top or bottom), the first whole in the frame.
- `rig-photo` (drawn only when named): `rig` in front of a real photograph
  (one of backgrounds.PHOTOS, bundled with scikit-image and matplotlib),
  zoomed 1-2.5x past covering the frame, cropped anywhere, mirrored on half
  the frames, gain 0.6-1.4, Gaussian defocus 0.5-2 px; the mount is the
  rig's round post or, on half the frames, one of rig-unseen's kinds.
- `rig-sensor` (drawn only when named): `rig` through a colour camera's
  pipeline (sensor.py): lateral chromatic aberration (red and blue scaled
  by 1 +- 0.0005-0.003 about the principal point), a Bayer mosaic (RGGB,
  BGGR, GRBG or GBRG) with noise on the raw, white-balance gains 0.8-1.25,
  OpenCV demosaicing (bilinear, VNG or EA), gamma, an unsharp mask (amount
  0-1, sigma 0.5-1.5 px) on 60 % of frames, JPEG. The truth circle is the
  green (reference) channel's outline.
- `rig-motion` (drawn only when named): `rig` with motion during the
  exposure: the sphere turning (each of its three angles turns through up
  to MOTION_SWEEP_DEG, +- half that about the frame's pose, rendered as
  MOTION_STEPS sub-exposures averaged: a stage moving while the shutter is
  open) and, on
  half the frames, the whole image smeared along a line of up to
  MOTION_LINE_PX at any angle (the camera or its stand shaking). The truth
  pose is the middle of the sweep; the outline does not move.
Each frame's scene depends only on (family, seed, index), so frames can be
drawn in any order or in parallel and drawn again identically.
"""
import math

import numpy as np

from . import backgrounds, render, sensor

FAMILIES = ("clean", "shifts", "rig", "rig-unseen", "edge", "refuse")
# Families drawn only when named (not in an evaluation's default list); appended after FAMILIES so
# that no family's seed stream, and so no frame drawn before, changes.
EXTRA_FAMILIES = ("two-edge", "rig-photo", "rig-sensor", "rig-motion")
_FAMILY_ID = {name: i + 1 for i, name in enumerate(FAMILIES + EXTRA_FAMILIES)}
MAX_HIDDEN_RIM = 0.15
# rig-motion: each angle's sweep over the exposure (the whole turn, centred on the frame's pose) is
# drawn in [-MOTION_SWEEP_DEG, MOTION_SWEEP_DEG]
# (a stage at 30 deg/s behind a 1/30 s shutter turns the sphere 1 deg: the range reaches past
# that, to find where accuracy goes); the line smear in [0, MOTION_LINE_PX] px.
# render.MOTION_STEPS sub-exposures make up the sweep.
MOTION_SWEEP_DEG = 3.0
MOTION_LINE_PX = 10.0
POSE_RANGE = 30.0


def frame_rng(family, seed, index):
    return np.random.default_rng([_FAMILY_ID[family], int(seed), int(index)])


def _pose(rng):
    """Uniform in [-30, 30] per axis, to the 3 decimals a file name can hold."""
    pose = [round(float(v), 3) for v in rng.uniform(-POSE_RANGE, POSE_RANGE, 3)]
    return [0.0 if v == 0 else v for v in pose]


def _light(rng, max_angle_deg):
    """A light from within `max_angle_deg` of the camera axis (direction: toward the light)."""
    th = math.radians(rng.uniform(0, max_angle_deg))
    ph = rng.uniform(0, 2 * math.pi)
    return [math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)]


def _clean(rng, cam):
    return {"pose": _pose(rng), "distance_mm": cam.distance_mm, "shift_px": [0.0, 0.0],
            "background": {"kind": "uniform", "colour": [0.25, 0.25, 0.27]},
            "mount": None,
            "lights": [{"direction": [0.0, 0.0, 1.0], "intensity": 0.65, "colour": [1.0, 1.0, 1.0]}],
            "ambient": 0.3, "sheen": {"specular": 0.05, "power": 30.0},
            "exposure": 1.0, "vignetting": 0.0, "blur": None, "noise": None, "gamma": 1.0, "jpeg": 0,
            "seed": int(rng.integers(0, 2**31))}


def _shifts(rng, cam):
    s = _clean(rng, cam)
    s["distance_mm"] = float(cam.distance_mm * rng.uniform(0.9, 1.1))
    r = cam.at(distance_mm=s["distance_mm"]).radius_px()
    room_u = max(0.0, cam.width / 2 - r - 6)
    room_v = max(0.0, cam.height / 2 - r - 6)
    s["shift_px"] = [float(rng.uniform(-room_u, room_u)), float(rng.uniform(-room_v, room_v))]
    n = int(rng.integers(1, 4))
    total = rng.uniform(0.5, 0.9)
    share = rng.dirichlet(np.ones(n))
    s["lights"] = [{"direction": _light(rng, 60), "intensity": float(total * share[i]),
                    "colour": [float(c) for c in np.clip(1 + rng.normal(0, 0.04, 3), 0.85, 1.15)]}
                   for i in range(n)]
    s["ambient"] = float(rng.uniform(0.2, 0.5))
    s["sheen"] = {"specular": float(rng.uniform(0, 0.35)), "power": float(rng.uniform(8, 80))}
    s["exposure"] = float(rng.uniform(0.8, 1.2))
    s["blur"] = {"kind": "gauss", "px": float(rng.uniform(0, 1.0))}
    s["noise"] = {"read": float(rng.uniform(0, 4)), "shot": float(rng.uniform(0, 0.5))}
    s["gamma"] = float(rng.uniform(0.8, 1.25))
    level = rng.uniform(0.12, 0.45)
    s["background"] = {"kind": "uniform",
                       "colour": [float(np.clip(level + t, 0, 1)) for t in rng.normal(0, 0.03, 3)]}
    return s


_DARK_COLOURS = ([0.08, 0.08, 0.08], [0.3, 0.3, 0.32], [0.55, 0.56, 0.58], [0.15, 0.14, 0.13])
_OTHER_COLOURS = ([0.15, 0.3, 0.75], [0.75, 0.15, 0.12], [0.85, 0.7, 0.15], [0.9, 0.9, 0.88],
                  [0.55, 0.38, 0.2], [0.2, 0.6, 0.3])


def _mount_ok(scene, cam):
    return render.hidden_rim_fraction(scene, cam) <= MAX_HIDDEN_RIM


def _round_post(rng):
    """The `rig` family's mount: a round post under the sphere, dark, grey or metal, tilted."""
    return {"type": "post", "shape": "cylinder", "size_mm": float(rng.uniform(2.5, 7.0)),
            "tilt_x_deg": float(rng.uniform(-10, 10)), "tilt_z_deg": float(rng.uniform(-5, 5)),
            "colour": list(_DARK_COLOURS[rng.integers(len(_DARK_COLOURS))]),
            "specular": float(rng.uniform(0.05, 0.5)), "power": float(rng.uniform(10, 60))}


def _place_mount(s, rng, cam, draw):
    """s["mount"] drawn by draw(rng) until _mount_ok accepts it (the 20th draw at most)."""
    for _ in range(20):
        s["mount"] = draw(rng)
        if _mount_ok(s, cam):
            break


def _rig_camera(s, rng):
    """The rig's camera: vignetting up to 40 %, JPEG 60-95 on 80 % of frames."""
    s["vignetting"] = float(rng.uniform(0, 0.4))
    s["jpeg"] = int(rng.integers(60, 96)) if rng.random() < 0.8 else 0
    return s


def _rig(rng, cam):
    s = _shifts(rng, cam)
    kind = str(rng.choice(["uniform", "gradient", "clutter"]))
    s["background"] = backgrounds.draw(kind, rng, cam.width, cam.height)
    _place_mount(s, rng, cam, _round_post)
    return _rig_camera(s, rng)


def _unseen_mount(rng):
    kind = str(rng.choice(["post", "fork", "holder"]))
    colour = list(_OTHER_COLOURS[rng.integers(len(_OTHER_COLOURS))])
    common = {"colour": colour, "specular": float(rng.uniform(0.05, 0.4)), "power": float(rng.uniform(10, 60))}
    side = float(rng.choice([0.0, 90.0, 180.0]) + rng.uniform(-15, 15))
    if kind == "post":
        return {"type": "post", "shape": "box", "size_mm": float(rng.uniform(2.5, 6.0)),
                "turn_deg": float(rng.uniform(0, 90)), "tilt_x_deg": float(rng.uniform(-10, 10)),
                "tilt_z_deg": float(rng.uniform(-8, 8)), **common}
    if kind == "fork":
        return {"type": "fork", "from_deg": side, "prong_mm": float(rng.uniform(1.2, 3.0)),
                "spread_mm": float(rng.uniform(5, 12)), "depth_mm": float(rng.uniform(-5, 10)),
                "bar_mm": float(rng.uniform(8, 25)), **common}
    return {"type": "holder", "from_deg": side, "width_mm": float(rng.uniform(4, 14)),
            "thick_mm": float(rng.uniform(2, 6)), "depth_mm": float(rng.uniform(-4, 12)), **common}


def _rig_unseen(rng, cam):
    s = _shifts(rng, cam)
    kind = str(rng.choice(["noise", "stripes", "checker", "extreme"]))
    if kind == "extreme":
        level = rng.uniform(0.0, 0.06) if rng.random() < 0.5 else rng.uniform(0.92, 1.0)
        s["background"] = {"kind": "gradient", "a": [float(level)] * 3,
                           "b": [float(np.clip(level + rng.normal(0, 0.03), 0, 1))] * 3,
                           "angle_deg": float(rng.uniform(0, 360))}
    else:
        s["background"] = backgrounds.draw(kind, rng, cam.width, cam.height)
    _place_mount(s, rng, cam, _unseen_mount)
    s["vignetting"] = float(rng.uniform(0, 0.5))
    s["blur"] = {"kind": "disc", "px": float(rng.uniform(0, 1.5))}
    s["jpeg"] = int(rng.integers(50, 96)) if rng.random() < 0.8 else 0
    return s


def _against_edge(rng, s, cam, lo, hi):
    """Move the sphere (principal-point shift) so that a share in [lo, hi] of its outline lies beyond
    one frame edge: a centre at distance r cos(pi f) from the edge leaves the share f outside."""
    f = rng.uniform(lo, hi)
    r = cam.at(distance_mm=s["distance_mm"]).radius_px()
    dist = r * math.cos(math.pi * f)
    u0, v0 = cam.principal
    edge = str(rng.choice(["left", "right", "top", "bottom"]))
    if edge in ("left", "right"):
        cu = dist if edge == "left" else cam.width - dist
        room = max(0.0, cam.height / 2 - r - 2)
        cv = cam.height / 2 + rng.uniform(-room, room)
    else:
        cv = dist if edge == "top" else cam.height - dist
        room = max(0.0, cam.width / 2 - r - 2)
        cu = cam.width / 2 + rng.uniform(-room, room)
    s["shift_px"] = [float(cu - u0), float(cv - v0)]
    s["outside"] = {"edge": edge, "share": float(f)}
    return s


def _edge(rng, cam):
    return _against_edge(rng, _rig(rng, cam), cam, 0.02, 0.12)


def _refuse(rng, cam):
    s = _rig(rng, cam)
    kind = str(rng.choice(["none", "two", "cut"]))
    s["expect"] = "refuse"
    s["refuse"] = kind
    if kind == "none":
        s["sphere"] = False
    elif kind == "two":
        side = 1.0 if rng.random() < 0.5 else -1.0
        s["mount"] = None
        s["shift_px"] = [float(-side * rng.uniform(130, 160)), float(rng.uniform(-40, 40))]
        s["others"] = [{"centre_mm": [float(side * rng.uniform(2.15, 2.4) * cam.radius_mm),
                                      float(rng.uniform(-0.3, 0.3) * cam.radius_mm),
                                      float(rng.uniform(-0.5, 0.5) * cam.radius_mm)],
                        "pose": _pose(rng)}]
    else:
        _against_edge(rng, s, cam, 0.2, 0.45)
    return s


def _outline_x(x_mm, depth, big, f_px):
    """Where a sphere of radius `big` at lateral offset x_mm and depth `depth` from the camera
    (in its horizontal plane) projects: (centre, radius) in px along the image row, from the two
    rays that graze it (an off-axis sphere's outline is wider than f R / depth)."""
    a = math.atan2(x_mm, depth)
    half = math.asin(big / math.hypot(x_mm, depth))
    lo, hi = f_px * math.tan(a - half), f_px * math.tan(a + half)
    return (lo + hi) / 2, (hi - lo) / 2


def _two_edge(rng, cam):
    """A `refuse` frame of the kind `two` whose second sphere has a share in [0.1, 0.45] of its
    outline beyond the left or right frame edge (its outline's centre at r2 cos(pi f) from the
    edge, r2 its half width along the row through the centres), none beyond the top or bottom, the
    first whole in the frame (both 6 px to spare vertically), 2.15-2.4 first radii from it (less
    where the frame has no room)."""
    s = _rig(rng, cam)
    s["expect"] = "refuse"
    s["refuse"] = "two"
    s["mount"] = None
    big, f_px = cam.radius_mm, cam.f_px
    r = cam.at(distance_mm=s["distance_mm"]).radius_px()
    side = 1.0 if rng.random() < 0.5 else -1.0          # +1: the second sphere beyond the right edge
    share = float(rng.uniform(0.1, 0.45))
    gap = float(rng.uniform(2.15, 2.4))
    z = float(rng.uniform(-0.5, 0.5) * big)
    y = float(rng.uniform(-0.3, 0.3) * big)
    depth = s["distance_mm"] - z
    # the second outline spans the rows v1 - up +- down (_outline_x in the vertical plane: the rows whose
    # planes through the camera graze the sphere, exact whatever its x); both keep 6 px from top and bottom
    up, down = _outline_x(y, depth, big, f_px)
    reach = max(r, abs(up) + down)
    room = max(0.0, cam.height / 2 - reach - 6)
    v1 = cam.height / 2 + rng.uniform(-room, room)
    # the second outline's radius depends on its offset, the offset on its radius: a few rounds
    x_mm, r2 = 0.0, r
    for _ in range(6):
        u2 = cam.width / 2 + side * (cam.width / 2 - r2 * math.cos(math.pi * share))
        u1 = min(max(u2 - side * gap * r, r + 6), cam.width - r - 6)
        x_mm = (u2 - u1) * depth / f_px
        c2, r2 = _outline_x(x_mm, depth, big, f_px)
        x_mm *= (u2 - u1) / c2
    u0, v0 = cam.principal
    s["shift_px"] = [float(u1 - u0), float(v1 - v0)]
    s["others"] = [{"centre_mm": [float(x_mm), y, z], "pose": _pose(rng)}]
    s["other_outside"] = {"edge": "right" if side > 0 else "left", "share": share}
    return s


def _rig_photo(rng, cam):
    """`rig` in front of a real photograph (backgrounds.PHOTOS, drawn by backgrounds.draw("photo")):
    half the frames the rig's round post, half a mount of rig-unseen's kinds."""
    s = _shifts(rng, cam)
    s["background"] = backgrounds.draw("photo", rng, cam.width, cam.height)
    _place_mount(s, rng, cam, _unseen_mount if rng.random() < 0.5 else _round_post)
    return _rig_camera(s, rng)


def _rig_sensor(rng, cam):
    """`rig` through a colour camera's pipeline (sensor.py, its parameters drawn by sensor.draw):
    lateral colour, Bayer mosaic, white balance, demosaicing, sharpening."""
    s = _rig(rng, cam)
    s["sensor"] = sensor.draw(rng)
    return s


def _rig_motion(rng, cam):
    """`rig` with the sphere turning while the shutter is open and, on half the frames, a line
    smear of the whole image (render.render reads the "motion" record)."""
    s = _rig(rng, cam)
    shake = rng.random() < 0.5
    s["motion"] = {"sweep_deg": [float(v) for v in rng.uniform(-MOTION_SWEEP_DEG, MOTION_SWEEP_DEG, 3)],
                   "line_px": float(rng.uniform(0.0, MOTION_LINE_PX)) if shake else 0.0,
                   "line_deg": float(rng.uniform(0.0, 180.0))}
    return s


_DRAW = {"clean": _clean, "shifts": _shifts, "rig": _rig, "rig-unseen": _rig_unseen, "edge": _edge,
         "refuse": _refuse, "two-edge": _two_edge, "rig-photo": _rig_photo, "rig-sensor": _rig_sensor,
         "rig-motion": _rig_motion}


def draw_scene(family, seed, index, cam):
    """The scene of frame `index` of `family` for `seed` (a JSON-ready dict, render.render's input)."""
    if family not in _DRAW:
        raise ValueError(f"unknown family {family!r} (valid: {', '.join(FAMILIES + EXTRA_FAMILIES)})")
    return _DRAW[family](frame_rng(family, seed, index), cam)
