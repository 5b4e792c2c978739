"""The printed centre weighed against the refined centre (training/refine.py CENTRE_FUSE_PX,
fused_centre; preprocess.find_sphere's cov; docs/refine.md step 9).

- `edge` seed 508 frames 40 and 43 and seed 501 frame 33: the sphere 2-7 px past the bottom or top
  edge of the frame, with the post below. Few rims lie above and below, so the localisation holds
  the centre loosely along the vertical, and it printed 0.51-0.56 px off. The
  refined centre, held by the whole texture, is 0.11-0.18 px off. Weighed by the rims'
  covariance, the printed centre is 0.25-0.34 px off.

The C runtime prints the centre the Python reference prints (`python -m training.refine run`)."""
import math

import numpy as np
import pytest

from training import preprocess as pp
from training import refine as rf
from v2_raycast_cases import circle_error, params, poseinfer_lines, python_results, render_seeded

CASES = [(("edge", 40, "-21.039_6.094_21.457.png"), 508),
         (("edge", 43, "-28.1_21.028_-0.591.png"), 508),
         (("edge", 33, "-19.1_-26.715_-10.204.png"), 501)]


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    return render_seeded(tmp_path_factory.mktemp("centre_fuse"), CASES)


def _rims_on(angles_deg, r=140.0, jitter=0.0, seed=0):
    rng = np.random.default_rng(seed)
    a = np.radians(np.asarray(angles_deg, float))
    rr = r + jitter * rng.standard_normal(a.size)
    return list(rr * np.cos(a)), list(rr * np.sin(a))


def test_covariance_follows_the_rims():
    p = params()
    xs, ys = _rims_on(np.arange(0, 360, 3), jitter=0.2)
    whole = pp._centre_covariance(xs, ys, 0.0, 0.0, 140.0, p)
    xs, ys = _rims_on(list(range(-50, 51, 3)) + list(range(130, 231, 3)), jitter=0.2)
    sides = pp._centre_covariance(xs, ys, 0.0, 0.0, 140.0, p)
    # all round: about s2 * 2 / n on both axes; on the left and right arcs only (+-50 deg), y held
    # more than 3x looser
    assert whole[0] == pytest.approx(whole[2], rel=0.3) and abs(whole[1]) < 0.2 * whole[0]
    assert sides[2] > 3 * sides[0] and sides[2] > 3 * whole[2]
    # too few rims
    xs, ys = _rims_on(np.arange(0, 70, 10))
    assert pp._centre_covariance(xs, ys, 0.0, 0.0, 140.0, p) is None


def test_fused_centre_leans_where_the_rims_are_loose():
    f = (10.3, 20.4)
    tight = rf.fused_centre((10.0, 20.0), (1e-3, 0.0, 1e-3), f)
    assert math.hypot(tight[0] - 10.0, tight[1] - 20.0) < 0.05  # rims all round: the rims' centre
    loose_y = rf.fused_centre((10.0, 20.0), (1e-3, 0.0, 0.1), f)
    assert abs(loose_y[0] - 10.0) < 0.05 and loose_y[1] == pytest.approx(20.4, abs=0.05)


def test_printed_centre_in_c_and_python(frames, tmp_path, poseinfer, timeout_scale):
    lines = poseinfer_lines(poseinfer, [path for path, _ in frames], tmp_path, ("--timings",),
                            timeout_scale)
    pys = python_results([path for path, _ in frames], lines)
    for (path, truth), line, (py, cov) in zip(frames, lines, pys):
        assert line["confident"] is True, line
        # the localisation's centre is off along the loose axis (what this guards)
        found = (line["cx"], line["cy"], line["r"])
        ec, _ = circle_error(found, truth)
        assert ec > 0.5, (path.name, ec)
        c = line["circle"]
        ec, er = circle_error((c[0] - 0.5, c[1] - 0.5, c[2]), truth)
        assert ec <= 0.4 and er <= 0.5, (path.name, ec, er)
        assert c[2] == pytest.approx(found[2], abs=0.01)  # the radius is the localisation's
        assert cov[2] > 1.5 * cov[0], (path.name, cov)  # few rims above and below: y is loose
        # the Python reference, from the C side's network angles
        assert np.abs(np.array(py["circle"]) - c).max() < 2e-3, (path.name, py["circle"], c)
