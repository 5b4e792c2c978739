"""sphere-crop-v2 refuses a weakly fitted second sphere that looks like the sphere
(training/preprocess.py SECOND_WEAK, WEAK_SHARE, TEXTURE_TOL, _texture_steps; docs/interfaces.md
step 5).

- `refuse` seed 446 frame 47: two spheres on a dark gradient, the second's dark limb on the dark
  backdrop and part of it outside the frame. Its fit, tried again as the sphere's weak fit is,
  reaches only 0.39, below min_support, and the frame was answered with a confident pose of the
  other sphere. `two-edge` seed 502 frame 66 (the second sphere partly outside the frame) too,
  at 0.41. `refuse` seed 498 frame 64 (two spheres on clutter, the second 2 % outside the frame)
  at 0.328, below the first SECOND_WEAK of 0.33. Lit and textured as the sphere is, each second
  circle is now a second sphere: "two spheres in frame".
- The clutter circles beside a sphere that come nearest to the rule stay what they are, and
  their frames are answered within the limits: `edge` seed 418 frame 48 (a lit disk, 0.41, its
  texture 2 steps off the sphere's), `edge` seed 424 frame 41 (0.375, shading 0.37 of the
  sphere's) and `rig` seed 443 frame 3 (texture and shading like the sphere's, 0.28 of beside
  support).

The C runtime gives the same errors and circles as Python."""
import math

import cv2
import numpy as np
import pytest

from training import preprocess as pp
from v2_raycast_cases import (CAMERA, assert_within_limits, params, poseinfer_lines, render_seeded,
                              without_colours)

SECOND = [(("refuse", 47, "-13.186_27.459_26.541.png"), 446),
          (("two-edge", 66, "-4.515_-6.421_-1.939.png"), 502),
          (("refuse", 64, "-3.589_28.381_-19.451.png"), 498)]
CLUTTER = [(("edge", 48, "-6.016_-28.666_24.941.png"), 418),
           (("edge", 41, "9.714_29.617_2.478.png"), 424),
           (("rig", 3, "-5.652_12.836_-18.571.png"), 443)]


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    folder = tmp_path_factory.mktemp("weak_second")
    return render_seeded(folder, SECOND), render_seeded(folder, CLUTTER)


def _find(path):
    return pp.find_sphere(cv2.imread(str(path), cv2.IMREAD_COLOR), params(), CAMERA)


def _error(path):
    with pytest.raises(pp.NoSphere) as e:
        _find(path)
    return str(e.value)


def test_weak_second_sphere_refused(frames, monkeypatch):
    for path, _ in frames[0]:
        assert _error(path).startswith("two spheres in frame"), path.name
    # without the rule each frame is answered (what this guards)
    monkeypatch.setattr(pp, "SECOND_WEAK", 2.0)
    for path, _ in frames[0]:
        _find(path)


def test_clutter_circles_stay_clutter(frames, monkeypatch):
    assert_within_limits(frames[1], params())
    # each of the rule's tests is what keeps one of them answered (with the colours' test off,
    # which keeps them answered too)
    (lit_disk, _), (dim_disk, _), (like, _) = frames[1]
    without_colours(monkeypatch)
    monkeypatch.setattr(pp, "TEXTURE_TOL", math.inf)
    assert _error(lit_disk).startswith("two spheres in frame")
    monkeypatch.undo()
    without_colours(monkeypatch)
    monkeypatch.setattr(pp, "WEAK_SHARE", 0.3)
    assert _error(dim_disk).startswith("two spheres in frame")
    monkeypatch.undo()
    without_colours(monkeypatch)
    monkeypatch.setattr(pp, "SECOND_WEAK", 0.25)
    assert _error(like).startswith("two spheres in frame")


def _rings(edges, r=120.0, size=400):
    """A grey frame with a disk of radius r at its middle whose brightness flips at each radius
    in `edges` (fractions of r): a step of 60 on every ray there."""
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64)
    d = np.hypot(xx - size / 2, yy - size / 2) / r
    level = 100.0 + 60.0 * (np.searchsorted(np.sort(edges), d) % 2)
    img = np.where(d < 1.0, level, 40.0)
    return np.repeat(img[:, :, None], 3, axis=2).astype(np.uint8)


@pytest.mark.parametrize("edges", [[], [0.5], [0.3, 0.45, 0.6, 0.75], [0.1, 0.9], [0.1, 0.5, 0.9]])
def test_texture_steps_counts_the_bands_inside(edges):
    """Only the steps from 0.2 r to 0.8 r count, one per band edge crossed."""
    img = _rings(edges)
    p = pp.params()
    dirs = pp._ray_dirs(p["rays"])
    want = sum(1 for e in edges if 0.2 < e < 0.8)
    assert pp._texture_steps(img, dirs, (200.0, 200.0, 120.0), p) == want


def test_texture_steps_needs_8_rays_in_the_frame():
    """A circle mostly outside the frame (its centre beyond the left edge, near the bottom, so
    that both edges cut its rays): with 7 rays whose samples all lie in it, too few to tell
    (None); with 8, a count."""
    img = _rings([0.5])
    p = pp.params()
    dirs = pp._ray_dirs(p["rays"])
    for y, n in ((386.0, 7), (382.0, 8)):
        bad = pp._ray_scores(img, dirs, -23.0, y, 60.0, 36.0)[2]  # the samples _texture_steps takes
        assert int((~bad).sum()) == n, (y, int((~bad).sum()))
        steps = pp._texture_steps(img, dirs, (-23.0, y, 120.0), p)
        assert (steps is None) == (n < 8), (n, steps)


def test_same_answers_in_c(frames, tmp_path, poseinfer, timeout_scale):
    paths = [path for path, _ in frames[0] + frames[1]]
    # unrefined: a refined answer's circle can be the rim found from the refined circle
    # (test_v2_rim_check.py)
    lines = poseinfer_lines(poseinfer, paths, tmp_path, ("--no-refine",), timeout_scale, rc=1)
    for path, line in zip(paths, lines):
        try:
            cx, cy, r, _ = _find(path)
        except pp.NoSphere as e:
            assert line.get("error") == f"preprocess: {e}", line
        else:
            assert line["circle"] == [round(cx + 0.5, 3), round(cy + 0.5, 3), round(r, 3)], line
