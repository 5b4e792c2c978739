"""sphere-crop-v2 leaves the coarse edges of a dominant orientation out of the coarse stage
(training/preprocess.py _drop_stripes, STRIPE_SHARE; docs/interfaces.md step 2): fine stripes
behind the sphere give more coarse edges than its rim, all one way, and their votes add up to peaks
25-60 px off it. Two `rig-unseen` frames of the independent ray-caster (bench/raycast) with fine
stripes behind the sphere: frame 12 of seed 438 was refused as "no sphere found in frame" and is
now answered within 0.5 px and 0.5 % of the truth; frame 43 of seed 427 was answered 7 px off and
is now within 1 px. The C runtime bins the orientations alike and gives the same circles."""
import cv2
import numpy as np
import pytest

from training import preprocess as pp
from v2_raycast_cases import (CAMERA, assert_off_centre, assert_same_circles_in_c, assert_within_limits,
                              circle_error, params, render_seeded, without_wide_gap_retry)

REFUSED = [(("rig-unseen", 12, "4.117_13.458_-23.018.png"), 438)]
FAR_OFF = [(("rig-unseen", 43, "14.777_-7.563_-12.605.png"), 427)]


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    folder = tmp_path_factory.mktemp("stripes")
    return render_seeded(folder, REFUSED), render_seeded(folder, FAR_OFF)


def without_the_filter(monkeypatch):
    monkeypatch.setattr(pp, "_drop_stripes", lambda x, y, gx, gy: (x, y, gx, gy))


def test_refused_frame_answered(frames, monkeypatch):
    p = params()
    imgs = assert_within_limits(frames[0], p)
    without_the_filter(monkeypatch)  # what this guards: refused
    without_wide_gap_retry(monkeypatch)
    with pytest.raises(pp.NoSphere, match="no sphere found"):
        pp.find_sphere(imgs[0], p, CAMERA)


def test_far_off_frame_near(frames, monkeypatch):
    p = params()
    (path, truth), = frames[1]
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    ec, er = circle_error(pp.find_sphere(img, p, CAMERA), truth)
    assert ec <= 1.0 and er <= 0.5, (ec, er)
    without_the_filter(monkeypatch)  # what this guards: a circle 7 px off
    assert_off_centre([img], frames[1], p, 5.0)


def edges_of(bins):
    """Edges whose gradients lie in the middle of the given orientation bins, in that order."""
    ang = np.array(bins) * np.pi / 16
    gx, gy = np.round(400 * np.cos(ang)).astype(np.int64), np.round(400 * np.sin(ang)).astype(np.int64)
    i = np.arange(len(bins), dtype=np.int64)
    return i, i + 1000, gx, gy


def test_only_a_dominant_orientation_is_dropped():
    # every bin 4 edges, bin 5 60 (share 0.5 >= STRIPE_SHARE): bin 5 goes, the rest keep their order
    bins = [k for k in range(16) for _ in range(4)] + [5] * 56
    rng = np.random.default_rng(3)
    bins = list(rng.permutation(bins))
    x, y, gx, gy = edges_of(bins)
    assert list(pp._orientation_bins(gx, gy)) == bins
    kx, ky, kgx, kgy = pp._drop_stripes(x, y, gx, gy)
    want = [i for i, b in enumerate(bins) if b != 5]
    assert list(kx) == want and list(ky) == [i + 1000 for i in want]
    assert list(kgx) == list(gx[want]) and list(kgy) == list(gy[want])
    # below the share (bin 5 holds 40 of 100): nothing is dropped
    bins = [k for k in range(16) for _ in range(4)] + [5] * 36
    x, y, gx, gy = edges_of(bins)
    assert 40 < pp.STRIPE_SHARE * 100
    assert all(len(a) == 100 for a in pp._drop_stripes(x, y, gx, gy))
    # at the share (45 of 100): dropped
    bins = [k for k in range(16) for _ in range(4)] + [5] * 36
    bins[:5] = [5] * 5  # bin 0 gives 4 and bin 1 one edge to bin 5: 45 of 100
    x, y, gx, gy = edges_of(bins)
    assert pp.STRIPE_SHARE * 100 == 45.0
    assert 5 not in pp._orientation_bins(*pp._drop_stripes(x, y, gx, gy)[2:])
    # a second bin also above STRIPE_DROP times the median goes too; one at it stays
    bins = [k for k in range(16) for _ in range(4)] + [5] * 96 + [6] * 9 + [7] * 8
    x, y, gx, gy = edges_of(bins)
    kept = pp._orientation_bins(*pp._drop_stripes(x, y, gx, gy)[2:])
    assert sorted(set(kept)) == [k for k in range(16) if k not in (5, 6)]


def test_same_circles_in_c(frames, tmp_path, poseinfer, timeout_scale):
    assert_same_circles_in_c(poseinfer, [path for path, _ in frames[0] + frames[1]], tmp_path, timeout_scale)
