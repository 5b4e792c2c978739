"""The ray-caster's `rig-motion` family (bench/raycast/families.py, render.py): the rig's scene with the
sphere turning while the shutter is open and a line smear of the whole image. The family draws and
draws again identically from (seed, index) within its documented ranges; the sub-exposures sweep
the pose about the frame's own (its truth), the backdrop stays where it is, and the smear spreads a
point along its line (that every family keeps its seed stream: test_raycast_streams.py)."""
import math
import os
import sys

import cv2
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "bench"))

from raycast import camera, families, frames, render  # noqa: E402

# A quarter of the reference frame with 4x the pixel pitch (sphere radius about 33 px): fast.
SMALL = camera.Camera(width=160, height=128, pixel_mm=0.0384)
TEX = np.random.default_rng(3).uniform(0, 1, (64, 128, 3)).astype(np.float32)


def test_family_draws_again_identically():
    a = frames.make_frame("rig-motion", 700, 4, SMALL, TEX, supersample=2)
    b = frames.make_frame("rig-motion", 700, 4, SMALL, TEX, supersample=2)
    assert a[0] == b[0] and a[1] == b[1] and a[2] == b[2]
    # the rest of the scene is the rig family's kind of scene, and the outline does not move
    assert a[2]["scene"]["mount"]["type"] == "post"
    assert a[2]["circle"] == [round(c, 4) for c in render.circle(a[2]["scene"], SMALL)]


def test_motion_within_its_ranges():
    smeared = 0
    for i in range(40):
        m = families.draw_scene("rig-motion", 700, i, SMALL)["motion"]
        assert len(m["sweep_deg"]) == 3 and all(abs(v) <= families.MOTION_SWEEP_DEG for v in m["sweep_deg"])
        assert 0.0 <= m["line_px"] <= families.MOTION_LINE_PX and 0.0 <= m["line_deg"] <= 180.0
        smeared += m["line_px"] > 0
    assert 10 <= smeared <= 30, smeared       # about half the frames


def _scene(sweep):
    s = families.draw_scene("rig-motion", 700, 4, SMALL)
    s["motion"] = {"sweep_deg": sweep, "line_px": 0.0, "line_deg": 0.0}
    return s


def test_sub_exposures_sweep_about_the_pose():
    still = _scene([0.0, 0.0, 0.0])
    ref = render.radiance(still, SMALL, TEX, supersample=2)
    # no sweep: the exposure is the frame's pose alone
    assert np.allclose(render.exposure_radiance(still, SMALL, TEX, supersample=2), ref, atol=1e-6)
    moving = _scene([0.0, 8.0, 0.0])
    img = render.exposure_radiance(moving, SMALL, TEX, supersample=2)
    hit = render.trace(still, SMALL, *np.meshgrid(np.arange(SMALL.width) + 0.5, np.arange(SMALL.height) + 0.5))[0]
    hit = hit.reshape(SMALL.height, SMALL.width)
    # the backdrop is where it was (to the rounding of the mean); the sphere is smeared: it differs from the still frame, and
    # from each end of the sweep more than from its middle (the truth)
    # backdrop pixels none of whose 3 x 3 neighbours sees anything else (those beside the outline
    # are supersampled, and their sub-rays can meet the sphere)
    back = cv2.erode((hit == render.BACKDROP).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert back.sum() > 0.5 * back.size
    assert np.allclose(img[back], ref[back], atol=1e-6)
    sphere = hit == render.SPHERE
    ends = [render.radiance(dict(still, pose=[p + d for p, d in zip(still["pose"], (0.0, s, 0.0))]), SMALL, TEX, 2)
            for s in (-4.0, 4.0)]
    diff = lambda x: float(np.abs(img[sphere] - x[sphere]).mean())
    assert diff(ref) > 1e-3
    assert diff(ref) < min(diff(e) for e in ends)


def test_sub_exposures_at_the_middles_of_equal_steps(monkeypatch):
    # the poses rendered: pose + ((k + 0.5) / MOTION_STEPS - 0.5) sweep, k = 0 .. MOTION_STEPS - 1,
    # so that the exposure spans pose +- sweep / 2 and the sweep in the scene is the whole turn
    scene = _scene([2.0, -1.0, 0.5])
    poses = []
    monkeypatch.setattr(render, "radiance", lambda s, cam, tex, ss: poses.append(s["pose"]) or np.zeros((1, 1, 3), np.float32))
    render.exposure_radiance(scene, SMALL, TEX, supersample=2)
    n = render.MOTION_STEPS
    assert len(poses) == n
    for k, pose in enumerate(poses):
        t = (k + 0.5) / n - 0.5
        assert np.allclose(pose, [p + t * s for p, s in zip(scene["pose"], scene["motion"]["sweep_deg"])])
    span = np.array(poses[-1]) - np.array(poses[0])
    assert np.allclose(span, np.array(scene["motion"]["sweep_deg"]) * (n - 1) / n)


def test_smear_is_applied():
    scene = _scene([0.0, 0.0, 0.0])
    still = render.render(scene, SMALL, TEX, supersample=2)
    smeared = render.render(dict(scene, motion=dict(scene["motion"], line_px=6.0, line_deg=20.0)), SMALL, TEX, 2)
    assert np.abs(still.astype(np.int16) - smeared.astype(np.int16)).max() > 20


def test_line_smear_spreads_a_point_along_its_line():
    for length, angle in ((5.0, 0.0), (6.0, 30.0), (3.2, 135.0), (10.0, 77.0)):
        k = render._line_kernel(length, angle).astype(np.float64)
        assert abs(k.sum() - 1.0) < 1e-6
        n = k.shape[0] // 2
        ys, xs = np.mgrid[-n:n + 1, -n:n + 1]
        assert abs((k * xs).sum()) < 1e-6 and abs((k * ys).sum()) < 1e-6      # centred
        a = math.radians(angle)
        along = xs * math.cos(a) + ys * math.sin(a)
        across = -xs * math.sin(a) + ys * math.cos(a)
        # a uniform segment of length L has variance L^2 / 12 along it, and the taps' tent adds 1/6
        # (its own variance); across it only the tent's, at most 1/6 (none on a row or column)
        assert abs((k * along ** 2).sum() - (length ** 2 / 12 + 1 / 6)) < 0.02, (length, angle)
        assert (k * across ** 2).sum() < 1 / 6 + 0.02


def test_breakdown_tags():
    import realscene
    scene = families.draw_scene("rig-motion", 700, 4, SMALL)
    scene["motion"] = {"sweep_deg": [1.2, -1.6, 0.0], "line_px": 7.5, "line_deg": 40.0}
    tags = realscene.scene_tags(scene)
    assert tags["sweep"] == "sweep 2-3°" and tags["smear"] == "smear 6-10 px"
    scene["motion"] = {"sweep_deg": [0.3, 0.0, 0.0], "line_px": 0.0, "line_deg": 40.0}
    tags = realscene.scene_tags(scene)
    assert tags["sweep"] == "sweep < 1°" and tags["smear"] == "no smear"
    # frames without motion have no such rows in the breakdown
    assert "sweep" not in realscene.scene_tags(families.draw_scene("rig", 700, 4, SMALL))
