"""What holds the sphere on a rig, as solids in the world frame (mm), from a parameter dict.

- `post`: a round (`cylinder`) or square (`box`) post under the sphere, its
  top sunk into the sphere's south side, tilted a little;
- `fork`: two round prongs, a crossbar and a handle coming in from one side of the
  image (`from_deg`: 0 = right, 90 = top, 180 = left), in front of or
  around the sphere's equator, their ends touching the sphere;
- `holder`: one flat arm (a box) coming in from one side.
A mount hides part of the sphere's outline; `families` keeps that part at
or under 15 % of the rim (measured by rays, `hidden_rim_fraction`).
"""
import numpy as np

from . import shapes

LONG_MM = 300.0   # the mount runs out of the frame


def _rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def solids(p, sphere_radius):
    """List of (hit function of (o, d), material dict) for mount parameters `p` (None: no mount)."""
    if p is None:
        return []
    mat = {"colour": p["colour"], "specular": p.get("specular", 0.2), "power": p.get("power", 20.0)}
    R = sphere_radius
    if p["type"] == "post":
        tilt = _rot_z(np.radians(p["tilt_z_deg"])) @ _rot_x(np.radians(p["tilt_x_deg"]))
        down = tilt @ np.array([0.0, -1.0, 0.0])
        top = 0.7 * R * down          # the post's top is sunk 0.3 R into the sphere
        if p["shape"] == "cylinder":
            return [(lambda o, d, b=top, a=down, r=p["size_mm"]: shapes.cylinder_hit(o, d, b, a, r, LONG_MM), mat)]
        rot = tilt @ _rot_y(np.radians(p["turn_deg"]))
        centre = top + down * (LONG_MM / 2)
        half = (p["size_mm"], LONG_MM / 2, p["size_mm"])
        return [(lambda o, d, c=centre, m=rot, h=half: shapes.box_hit(o, d, c, m, h), mat)]
    a = np.radians(p["from_deg"])
    out = np.array([np.cos(a), np.sin(a), 0.0])       # from the sphere toward where the mount comes from
    side = np.array([-np.sin(a), np.cos(a), 0.0])
    ez = np.array([0.0, 0.0, 1.0])
    if p["type"] == "fork":
        parts = []
        r = p["prong_mm"]
        bar_at = R + p["bar_mm"]                       # distance of the crossbar from the sphere centre
        for sgn in (-1.0, 1.0):
            off = sgn * p["spread_mm"] * side + p["depth_mm"] * ez
            # The prong's end sits where its axis meets the sphere surface, sunk by half its radius.
            along = np.sqrt(max(R * R - float(off @ off), 0.0)) - 0.5 * r
            base = off + out * along
            parts.append((lambda o, d, b=base, ax=out, rr=r, ln=bar_at - along:
                          shapes.cylinder_hit(o, d, b, ax, rr, ln), mat))
        bar_base = out * bar_at + p["depth_mm"] * ez - side * (p["spread_mm"] + r)
        parts.append((lambda o, d, b=bar_base, ax=side, rr=r * 1.2, ln=2 * (p["spread_mm"] + r):
                      shapes.cylinder_hit(o, d, b, ax, rr, ln), mat))
        handle = out * bar_at + p["depth_mm"] * ez      # the fork's handle runs out of the frame
        parts.append((lambda o, d, b=handle, ax=out, rr=r * 1.5: shapes.cylinder_hit(o, d, b, ax, rr, LONG_MM), mat))
        return parts
    if p["type"] == "holder":
        rot = np.stack([out, side, ez], axis=1)
        off = p["depth_mm"] * ez
        along = np.sqrt(max(R * R - float(off @ off), 0.0)) - 0.3 * p["thick_mm"]
        centre = off + out * (along + LONG_MM / 2)
        half = (LONG_MM / 2, p["width_mm"] / 2, p["thick_mm"] / 2)
        return [(lambda o, d, c=centre, m=rot, h=half: shapes.box_hit(o, d, c, m, h), mat)]
    raise ValueError(f"unknown mount type {p['type']!r} (valid: post, fork, holder)")
