"""The circle after refinement (training/refine.py RIM_CHECK_PCT, preprocess.rim_from;
docs/refine.md): where a confident answer's refined radius differs from the localisation's by more
than RIM_CHECK_PCT percent, the printed circle is the rim found from the refined circle.

- `edge` seed 426 frame 95 and seed 439 frame 78: the localisation's fit settled on an inner
  circle along one arc (1.9 and 1.8 px off centre, 1.1 % small); the refined radius is within
  0.1 % and the rim from the refined circle within 0.2 px.
- `rig-unseen` seed 439 frame 64: the last step took a backdrop's edge just outside the rim on
  one arc (0.9 px off, 0.6 % large).

The C runtime prints the circle the Python reference prints (`python -m training.refine run`)."""
import cv2
import numpy as np
import pytest

from training import preprocess as pp
from v2_raycast_cases import (RIM_CHECK_CASES as CASES, circle_error, params, poseinfer_lines,
                              python_results, render_seeded)


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    return render_seeded(tmp_path_factory.mktemp("rim_check"), CASES)


def test_rim_from_a_near_circle(frames):
    p = params()
    for path, truth in frames:
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        # from the truth moved about as far as a refined circle is off at worst (0.75 px, 0.2 %;
        # the refined centre's 99th percentile is 0.65 px): outside the limits on its own, well
        # within them after the rim step (0.13-0.28 px)
        start = (truth[0] + 0.6, truth[1] - 0.45, truth[2] * 1.002)
        ec, er = circle_error(pp.rim_from(img, start, p), truth)
        assert ec <= 0.4 and er <= 0.4, (path.name, ec, er)
    # nothing to find on a flat frame
    assert pp.rim_from(np.full((512, 640, 3), 90, np.uint8), (320.0, 256.0, 130.0), p) is None


def test_printed_circle_is_the_rim_in_c_and_python(frames, tmp_path, poseinfer, timeout_scale):
    lines = poseinfer_lines(poseinfer, [path for path, _ in frames], tmp_path, ("--timings",),
                            timeout_scale)
    pys = python_results([path for path, _ in frames], lines)
    for (path, truth), line, (py, _) in zip(frames, lines, pys):
        assert line["confident"] is True, line
        # the localisation's circle is off (what this guards), the printed one within limits
        found = (line["cx"], line["cy"], line["r"])
        ec, er = circle_error(found, truth)
        assert ec > 0.5 or er > 0.5, (path.name, ec, er)
        c = line["circle"]
        ec, er = circle_error((c[0] - 0.5, c[1] - 0.5, c[2]), truth)
        assert ec <= 0.5 and er <= 0.5, (path.name, ec, er)
        # the Python reference, from the C side's network angles
        assert py["confident"] is True, py
        assert np.abs(np.array(py["circle"]) - c).max() < 2e-3, (path.name, py["circle"], c)
