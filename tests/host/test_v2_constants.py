"""sphere-crop-v2's constants of the algorithm (not model parameters) are written twice: as the
module's numeric upper-case names in training/preprocess.py and as file-scope constexpr values of
the same lower-case name in host/libposeinfer/crop2.cpp. Each must have its twin, with the same
value, so that the two implementations stay bit-identical."""
import numbers
import re
from pathlib import Path

from training import preprocess as pp

CROP2 = Path(__file__).resolve().parents[2] / "host" / "libposeinfer" / "crop2.cpp"
CONSTEXPR = re.compile(r"^constexpr (int|double) ([a-z_][a-z0-9_]*) = ([-+0-9.eE]+);$", re.M)


def python_constants():
    return {name.lower(): value for name, value in vars(pp).items()
            if name.isupper() and isinstance(value, numbers.Real) and not isinstance(value, bool)}


def cpp_constants():
    return {name: (int(v) if kind == "int" else float(v)) for kind, name, v in CONSTEXPR.findall(CROP2.read_text())}


def test_every_constant_has_its_twin():
    py, cpp = python_constants(), cpp_constants()
    assert py, "no constants found in training/preprocess.py"
    assert set(py) == set(cpp), (sorted(set(py) - set(cpp)), sorted(set(cpp) - set(py)))
    for name, value in py.items():
        assert cpp[name] == value and type(cpp[name]) is type(value), (name, value, cpp[name])


def test_the_known_constants_are_read():
    """The reading itself: the constants this test was written with are among those found (a
    changed pattern that finds nothing on either side fails here, not silently above)."""
    known = {"grow_rounds", "limb_share", "limb_min", "second_in_frame", "cut_shade", "second_retry",
             "wide_out", "wide_below"}
    assert known <= set(python_constants()) and known <= set(cpp_constants())
