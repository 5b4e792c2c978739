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


def test_two_edge_frames():
    cam = camera.Camera()
    for i in range(4):
        s = families.draw_scene("two-edge", 500, i, cam)
        assert s["expect"] == "refuse" and s["refuse"] == "two" and s["mount"] is None
        cx, cy, r = render.circle(s, cam)
        assert r <= cx <= cam.width - r and r <= cy <= cam.height - r  # the first sphere whole
        u, half = _other_outline(s, cam)
        a = np.linspace(0, 2 * np.pi, 3600, endpoint=False)
        outside = np.mean((u + half * np.cos(a) < 0) | (u + half * np.cos(a) > cam.width))
        share = s["other_outside"]["share"]
        assert abs(outside - share) < 0.01 and 0.1 <= share <= 0.45, (i, outside, share)
        assert (u > cam.width / 2) == (s["other_outside"]["edge"] == "right")
        assert abs(u - cx) > r + half  # the two outlines apart
