"""sim/names.py: the one formatter/parser of `<x>_<y>_<z>.png`; every bad name is an error naming the file."""
import math

import numpy as np
import pytest

from sim.names import BadName, format_angle, format_name, parse_name, quantize

GOOD = {
    "12_-3_30.png": (12.0, -3.0, 30.0),
    "7.5_3.25_-14.125.png": (7.5, 3.25, -14.125),
    "0_0_0.png": (0.0, 0.0, 0.0),
    "-0.001_0.999_-30.png": (-0.001, 0.999, -30.0),
    "180_-180_90.png": (180.0, -180.0, 90.0),
    "0.5_-0.5_10.05.png": (0.5, -0.5, 10.05),
}

BAD = [
    "+1_2_3.png",            # plus sign
    "1_+2_3.png",
    "1e1_2_3.png",           # exponent
    "1_2_3E0.png",
    "1_2_3e-2.png",
    " 1_2_3.png",            # spaces
    "1_2_3 .png",
    "1 _2_3.png",
    "1_2_ 3.png",
    "01_2_3.png",            # leading zeros
    "1_-02_3.png",
    "00_2_3.png",
    "-00_2_3.png",
    "1.2345_2_3.png",        # 4 decimals
    "1_2_3.0001.png",
    "1._2_3.png",            # dot without digits
    ".5_2_3.png",            # no integer part
    "-.5_2_3.png",
    "1_2.png",               # missing parts
    "1_2_.png",
    "_2_3.png",
    "1__3.png",
    "1_2_3_4.png",           # an extra part
    "1_2_3",                 # wrong or missing extension
    "1_2_3.PNG",
    "1_2_3.jpg",
    "1_2_3.png.tmp",
    "1_2_3png",
    "nan_2_3.png",           # not numbers
    "NaN_0_0.png",
    "inf_0_0.png",
    "-inf_0_0.png",
    "1_2_x.png",
    "--1_2_3.png",
    "1,5_2_3.png",           # comma decimal
    "1-2_3_4.png",
    "１_2_3.png",            # non-ASCII digit
    "",
    ".png",
]


@pytest.mark.parametrize("name,pose", GOOD.items())
def test_good_names_parse(name, pose):
    assert parse_name(name) == pose
    assert parse_name(f"some/dir/{name}") == pose


@pytest.mark.parametrize("name", BAD)
def test_bad_names_are_errors_that_name_the_file(name):
    path = f"data/train/{name}"
    with pytest.raises(BadName) as e:
        parse_name(path)
    assert path in str(e.value)


def test_bad_name_is_a_value_error():
    assert issubclass(BadName, ValueError)


@pytest.mark.parametrize("pose", [(0, 0, 0), (12, -3, 30), (7.5, 3.25, -14.125), (-30, 30, -0.001),
                                  (29.9996, -29.9994, 0.0004), (-0.0004, 0.0, 1e-9)])
def test_round_trip(pose):
    name = format_name(*pose)
    assert parse_name(name) == quantize(*pose)
    assert format_name(*parse_name(name)) == name


def test_round_trip_random():
    rng = np.random.default_rng(0)
    for pose in rng.uniform(-180, 180, size=(2000, 3)):
        name = format_name(*pose)
        back = parse_name(name)
        assert np.all(np.abs(np.subtract(back, pose)) <= 0.0005 + 1e-9)
        assert format_name(*back) == name


def test_format_is_canonical():
    assert format_name(12, -3, 30) == "12_-3_30.png"
    assert format_name(7.5, 3.25, -14.125) == "7.5_3.25_-14.125.png"
    assert format_angle(-0.0) == "0"
    assert format_angle(-0.0004) == "0"      # rounds to zero: no '-0'
    assert format_angle(1.2345) in ("1.234", "1.235")
    assert format_angle(3.0) == "3"
    assert format_angle(-30) == "-30"


def test_formatting_nan_is_not_a_silent_label():
    with pytest.raises((ValueError, BadName)):
        name = format_name(math.nan, 0, 0)
        parse_name(name)
