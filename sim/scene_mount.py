"""The mount of a rig scene in VTK: a post under the sphere, optionally a cup or a fork holding it.

The mount is fixed in the world, as on a rig where the sphere sits on a post
that the stages turn about axes through the sphere's centre: the sphere's pose
changes, the post's image does not (docs/sim.md, "Rig scenes"). Every part
touches the sphere: a part of radius r ends where its rim meets the sphere,
at sqrt(R^2 - r^2) from the centre along its axis.

Geometry of one frame (sim/scene.draw's "mount"): the axis direction
    d = cos(tilt) (sin a, -cos a, 0) + sin(tilt) (0, 0, 1)
with a = direction_deg (0: from straight below, 90: from the image's right,
-90: from its left) and tilt toward the camera.
- post: radius post_radius_mm, from the sphere outward along d, length_mm long;
- cup: a closed cylinder of radius cup_radius_frac R and height cup_height_frac R
  whose rim meets the sphere, on a post;
- fork: two prongs (radius post_radius_mm / 2) at +-fork_spread_frac R beside the axis, their
  ends on the sphere, joined by a bar just beyond the sphere, on a post; the fork's
  plane is turned by fork_roll_deg about d (0: the prongs side by side in the image).
"""
import math

import numpy as np
from vtkmodules.vtkCommonMath import vtkMatrix4x4
from vtkmodules.vtkFiltersSources import vtkCylinderSource
from vtkmodules.vtkRenderingCore import vtkActor, vtkPolyDataMapper

MAX_PARTS = 5      # fork: two prongs, a bar, a post (cup: cup and post)
SIDES = 40         # facets around a part: the silhouette's sag at a 10 mm post is < 0.05 px


def axis_direction(direction_deg, tilt_deg):
    a, t = math.radians(direction_deg), math.radians(tilt_deg)
    return np.array([math.cos(t) * math.sin(a), -math.cos(t) * math.cos(a), math.sin(t)])


def parts(m, sphere_radius_mm):
    """[(start, end, radius)] in world mm of the cylinders of mount draw `m` (none for kind 'none')."""
    kind = m["kind"]
    if kind == "none":
        return []
    R = sphere_radius_mm
    d = axis_direction(m["direction_deg"], m["tilt_deg"])
    rp = min(m["post_radius_mm"], 0.9 * R)
    length = m["length_mm"]
    if kind == "post":
        a0 = math.sqrt(R * R - rp * rp)
        return [(a0 * d, (a0 + length) * d, rp)]
    if kind == "cup":
        rc = m["cup_radius_frac"] * R
        a0 = math.sqrt(R * R - rc * rc)
        a1 = a0 + m["cup_height_frac"] * R
        return [(a0 * d, a1 * d, rc), (a1 * d, (a1 + length) * d, min(rp, rc))]
    # fork
    e = np.cross(d, [0.0, 0.0, 1.0])
    e /= np.linalg.norm(e)
    roll = math.radians(m["fork_roll_deg"])
    e = math.cos(roll) * e + math.sin(roll) * np.cross(d, e)  # e turned about d
    o = m["fork_spread_frac"] * R
    rf = 0.5 * rp
    a_tip = math.sqrt(R * R - o * o)
    a_bar = R + 2.0 * rf
    return [(a_tip * d + o * e, a_bar * d + o * e, rf), (a_tip * d - o * e, a_bar * d - o * e, rf),
            (a_bar * d - (o + rf) * e, a_bar * d + (o + rf) * e, rf),
            (a_bar * d, (a_bar + length) * d, rp)]


def _cylinder_matrix(p0, p1):
    """vtkMatrix4x4 taking vtkCylinderSource's frame (axis +Y, centred) to the segment p0 -> p1."""
    axis = np.asarray(p1, float) - np.asarray(p0, float)
    y = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(y[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    x = np.cross(y, helper)
    x /= np.linalg.norm(x)
    z = np.cross(x, y)
    mid = (np.asarray(p0, float) + np.asarray(p1, float)) / 2.0
    m = vtkMatrix4x4()
    for i in range(3):
        m.SetElement(i, 0, float(x[i]))
        m.SetElement(i, 1, float(y[i]))
        m.SetElement(i, 2, float(z[i]))
        m.SetElement(i, 3, float(mid[i]))
    return m


class Mount:
    """MAX_PARTS cylinder actors in a sim.render.Renderer, set for each frame by `set`."""

    def __init__(self, renderer):
        self._parts = []
        for _ in range(MAX_PARTS):
            src = vtkCylinderSource()
            src.SetResolution(SIDES)
            src.CappingOn()
            mapper = vtkPolyDataMapper()
            mapper.SetInputConnection(src.GetOutputPort())
            actor = vtkActor()
            actor.SetMapper(mapper)
            actor.VisibilityOff()
            renderer.add_actor(actor)
            self._parts.append((src, actor))

    def set(self, m, sphere_radius_mm):
        """Show the mount of draw `m` (hide every part for kind 'none')."""
        cyl = parts(m, sphere_radius_mm)
        for i, (src, actor) in enumerate(self._parts):
            if i >= len(cyl):
                actor.VisibilityOff()
                continue
            p0, p1, r = cyl[i]
            src.SetRadius(float(r))
            src.SetHeight(float(np.linalg.norm(np.asarray(p1) - np.asarray(p0))))
            actor.SetUserMatrix(_cylinder_matrix(p0, p1))
            prop = actor.GetProperty()
            prop.SetColor(*(c / 255.0 for c in m["color"]))
            prop.SetSpecularColor(1.0, 1.0, 1.0)  # a plastic or painted sheen, not a metal's tint
            prop.SetAmbient(m["ambient"])
            prop.SetDiffuse(m["diffuse"])
            prop.SetSpecular(m["specular"])
            prop.SetSpecularPower(m["specular_power"])
            actor.VisibilityOn()
