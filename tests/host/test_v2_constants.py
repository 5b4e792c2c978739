"""sphere-crop-v2's constants of the algorithm (not model parameters) are written twice: as the
module's numeric upper-case names (numbers, or tuples of integers) in training/preprocess.py and
as file-scope constexpr values (or int arrays) of the same lower-case name in
host/libposeinfer/crop2.cpp. Each must have its twin, with the same
value, so that the two implementations stay bit-identical."""
import math
import numbers
import re
from pathlib import Path

import numpy as np

from training import preprocess as pp

CROP2 = Path(__file__).resolve().parents[2] / "host" / "libposeinfer" / "crop2.cpp"
CONSTEXPR = re.compile(r"^constexpr (int|double) ([a-z_][a-z0-9_]*) = ([-+0-9.eE]+);$", re.M)
ARRAY = re.compile(r"^constexpr int ([a-z_][a-z0-9_]*)\[(\d+)\] = \{([-+0-9, ]*)\};$", re.M)


def is_number(value):
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def python_constants():
    return {name.lower(): value for name, value in vars(pp).items()
            if name.isupper() and (is_number(value) or (isinstance(value, tuple) and value
                                                       and all(type(v) is int for v in value)))}


def cpp_constants():
    src = CROP2.read_text()
    out = {name: (int(v) if kind == "int" else float(v)) for kind, name, v in CONSTEXPR.findall(src)}
    for name, n, values in ARRAY.findall(src):
        items = tuple(int(v) for v in values.split(","))
        assert len(items) == int(n), (name, n, items)
        out[name] = items
    return out


def test_every_constant_has_its_twin():
    py, cpp = python_constants(), cpp_constants()
    assert py, "no constants found in training/preprocess.py"
    assert set(py) == set(cpp), (sorted(set(py) - set(cpp)), sorted(set(cpp) - set(py)))
    for name, value in py.items():
        assert cpp[name] == value and type(cpp[name]) is type(value), (name, value, cpp[name])


def test_the_known_constants_are_read():
    """The reading itself: the constants this test was written with are among those found (a
    changed pattern that finds nothing on either side fails here, not silently above)."""
    known = {"grow_rounds", "limb_share", "limb_min", "second_in_frame", "cut_shade", "cut_texture", "second_retry",
             "wide_out", "wide_below", "orient_slopes", "stripe_share", "stripe_drop",
             "second_weak", "weak_share", "texture_tol", "rim_near", "weak_peak", "colour_rings",
             "colour_sat", "colour_dark", "colour_tol"}
    assert known <= set(python_constants()) and known <= set(cpp_constants())


def test_orientation_slopes_are_the_bin_edges():
    """ORIENT_SLOPES are 1000 tan((2k + 1) pi / 32), rounded: the edges of 16 bins centred on
    multiples of pi/16; away from those edges the bins are atan2's."""
    assert pp.ORIENT_SLOPES == tuple(round(1000 * math.tan((2 * k + 1) * math.pi / 32)) for k in range(8))
    rng = np.random.default_rng(7)
    gx, gy = rng.integers(-2040, 2041, 50000), rng.integers(-2040, 2041, 50000)
    ang = np.mod(np.arctan2(gy, gx), np.pi) / (np.pi / 16)
    clear = np.abs(ang - np.floor(ang) - 0.5) > 0.01  # not within 1 % of a bin edge
    want = np.mod(np.floor(ang + 0.5).astype(np.int64), 16)
    assert (pp._orientation_bins(gx, gy)[clear] == want[clear]).all()
    assert list(pp._orientation_bins(np.array([0, 5, -5, 0, 5, -5]), np.array([0, 0, 0, 5, 5, 5]))) == [8, 0, 0, 8, 4, 12]
