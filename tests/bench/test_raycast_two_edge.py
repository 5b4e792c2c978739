"""The ray-caster's `two-edge` family (bench/raycast/families.py): two spheres, the second with
the drawn share of its outline beyond the left or right frame edge, the first whole in the frame;
the evaluation's families keep their seed streams (their frames do not change)."""
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "bench"))

from raycast import camera, families, render  # noqa: E402


def test_evaluation_families_keep_their_streams():
    assert families.FAMILIES == ("clean", "shifts", "rig", "rig-unseen", "edge", "refuse")
    assert [families._FAMILY_ID[f] for f in families.FAMILIES] == [1, 2, 3, 4, 5, 6]
    assert "two-edge" not in families.FAMILIES and "two-edge" in families.EXTRA_FAMILIES


def _other_outline(s, cam):
    """The second sphere's outline along the frame row through its centre: (centre u, half width),
    from where the rays stop meeting it (bisection on both sides)."""
    c = np.asarray(s["others"][0]["centre_mm"])
    u, v = camera.project(cam.at(distance_mm=s["distance_mm"]), [c], shift=s["shift_px"])[0]
    ends = []
    for sign in (1.0, -1.0):
        lo, hi = 0.0, 400.0
        for _ in range(30):
            m = (lo + hi) / 2
            hit, _, _, _ = render.trace(s, cam, [u + sign * m], [v])
            lo, hi = (m, hi) if hit[0] == render.OTHERS else (lo, m)
        ends.append(u + sign * lo)
    return (ends[0] + ends[1]) / 2, (ends[0] - ends[1]) / 2


def _other_outline_points(s, cam, n=720):
    """Points of the second sphere's outline [n, 2]: along n directions from its centre's image,
    where the rays stop meeting it (bisection, all directions at once)."""
    c = np.asarray(s["others"][0]["centre_mm"])
    u, v = camera.project(cam.at(distance_mm=s["distance_mm"]), [c], shift=s["shift_px"])[0]
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    lo, hi = np.zeros(n), np.full(n, 400.0)
    for _ in range(30):
        m = (lo + hi) / 2
        hit, _, _, _ = render.trace(s, cam, u + m * np.cos(a), v + m * np.sin(a))
        inside = hit == render.OTHERS
        lo, hi = np.where(inside, m, lo), np.where(inside, hi, m)
    return np.stack([u + lo * np.cos(a), v + lo * np.sin(a)], axis=1)


def _share_outside(points, cam):
    """The share of the outline's length beyond any of the four frame edges."""
    seg = np.linalg.norm(np.roll(points, -1, axis=0) - points, axis=1)
    length = (seg + np.roll(seg, 1)) / 2                # each point's part of the outline
    out = (points[:, 0] < 0) | (points[:, 0] > cam.width) | (points[:, 1] < 0) | (points[:, 1] > cam.height)
    return float(np.sum(length[out]) / np.sum(length))


def test_two_edge_frames():
    # 40 frames: the first sphere's row once let the second outline cross the top or bottom edge
    # on frames 15 and 29 of seed 500 (the recorded share then counted the left/right part only)
    cam = camera.Camera()
    for i in range(40):
        s = families.draw_scene("two-edge", 500, i, cam)
        assert s["expect"] == "refuse" and s["refuse"] == "two" and s["mount"] is None
        cx, cy, r = render.circle(s, cam)
        assert r <= cx <= cam.width - r and r <= cy <= cam.height - r  # the first sphere whole
        points = _other_outline_points(s, cam)
        assert 0 <= points[:, 1].min() and points[:, 1].max() <= cam.height, i  # none beyond top/bottom
        outside = _share_outside(points, cam)
        share = s["other_outside"]["share"]
        assert abs(outside - share) < 0.01 and 0.1 <= share <= 0.45, (i, outside, share)
        u, half = _other_outline(s, cam)
        assert (u > cam.width / 2) == (s["other_outside"]["edge"] == "right")
        assert abs(u - cx) > r + half  # the two outlines apart
