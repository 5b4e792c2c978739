"""sphere-crop-v2's support with the flank's two sides judged apart (training/preprocess.py
_support, docs/interfaces.md step 4).

- `rig-unseen` seed 0 frame 64 (a sphere held by a fork in front of fine stripes, period 7.8
  px) was refused as "no sphere found in frame": the stripes make colour steps as large as the
  rim's on the outer side of most rays, so the rim's step did not reach support_ratio times the
  median of the whole flank (inside and outside together) and even the true circle's support was
  0.398, below min_support. A rim that is support_ratio times the quieter side's median and at
  least every step of the busier side's now counts: the frame is answered within 0.5 px and
  0.5 %, and with the whole flank's median alone it is refused again.
- A synthetic disk on stripes: the true circle is supported, circles a few pixels off it are not
  (a stripe's step beside the rim is not the largest step of the busier side).

The C runtime gives the same circle as Python."""
import numpy as np
import pytest

from training import preprocess as pp
from v2_raycast_cases import (CAMERA, assert_same_circles_in_c, circle_error, params, render_frames,
                              without_wide_gap_retry)

FORK_ON_STRIPES = ("rig-unseen", 64, "-0.952_6.841_28.879.png")


def _whole_flank_support(img, dirs, cx, cy, r, p):
    """The support before the sides were judged apart: the whole flank's median only."""
    rho, score, bad = pp._ray_scores(img, dirs, cx, cy, r, p["support_flank_px"])
    peak, pos = pp._peaks(rho, score, p["support_edge_min"])
    flank = np.abs(rho[1:-1] - r) >= 2.0 * p["inlier_px"]
    med = pp._row_medians(score[:, flank])
    ok = peak & (np.abs(pos - r) <= p["inlier_px"]) & (score[:, 1:-1] >= p["support_ratio"] * med[:, None])
    return int((ok.any(axis=1) & ~bad).sum()) / len(dirs)


@pytest.fixture(scope="module")
def frame(tmp_path_factory):
    return render_frames(tmp_path_factory.mktemp("sides"), [FORK_ON_STRIPES])[0]


def _found(path):
    import cv2
    return pp.find_sphere(cv2.imread(str(path), cv2.IMREAD_COLOR), params(), CAMERA)


def test_fork_on_stripes_answered(frame, monkeypatch):
    path, truth = frame
    ec, er = circle_error(_found(path), truth)
    assert ec <= 0.5 and er <= 0.5, (path.name, ec, er)
    # with the whole flank's median alone the frame is refused (what this guards)
    monkeypatch.setattr(pp, "_support", _whole_flank_support)
    without_wide_gap_retry(monkeypatch)
    with pytest.raises(pp.NoSphere, match="no sphere found in frame"):
        _found(path)


def _disk_on_stripes(r=120.0, cx=320.0, cy=256.0, period=7.75):
    """A 640 x 512 frame: fine vertical sinusoidal stripes (90 +- 80) and over them a bright disk
    with a weaker diagonal texture (240 +- 10)."""
    yy, xx = np.mgrid[0:512, 0:640].astype(np.float64)
    stripes = 90.0 + 80.0 * np.sin(2.0 * np.pi * xx / period)
    texture = 240.0 + 10.0 * np.sin(2.0 * np.pi * (xx + yy) / 9.0)
    inside = np.clip(r - np.hypot(xx - cx, yy - cy) + 0.5, 0.0, 1.0)
    level = stripes + inside * (texture - stripes)
    return np.repeat(np.round(level)[:, :, None], 3, axis=2).astype(np.uint8)


def test_disk_on_stripes_supported_and_circles_off_it_not():
    # a circle off the rim by 1.5-5 px has a stripe's step within inlier_px of it on many rays,
    # and the disk's quiet side in its flank: the step is not the largest of the busier side's
    p = params()
    dirs = pp._ray_dirs(p["rays"])
    img = _disk_on_stripes()
    assert pp._support(img, dirs, 319.5, 255.5, 120.0, p) >= 0.9
    for dx, dr in ((0.0, 1.5), (0.0, 3.0), (0.0, 5.0), (0.0, -1.5), (0.0, -3.0), (4.0, 0.0)):
        off = pp._support(img, dirs, 319.5 + dx, 255.5, 120.0 + dr, p)
        assert off < p["min_support"], (dx, dr, off)


def test_same_circle_in_c(frame, tmp_path, poseinfer, timeout_scale):
    assert_same_circles_in_c(poseinfer, [frame[0]], tmp_path, timeout_scale)
