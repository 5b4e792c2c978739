"""The one place that formats and parses dataset file names `<x>_<y>_<z>.png`.

Each angle is a decimal number of degrees: an optional '-', an integer part
without leading zeros, and optionally '.' and 1 to 3 digits. No '+', exponent
or spaces (docs/conventions.md, "Dataset file names").
"""
import os
import re

_NUM = r"-?(?:0|[1-9][0-9]*)(?:\.[0-9]{1,3})?"
_NAME_RE = re.compile(rf"^({_NUM})_({_NUM})_({_NUM})\.png$")


class BadName(ValueError):
    """A file name that does not encode a pose; the message names the file."""


def format_angle(a):
    """Shortest decimal for angle `a` rounded to 3 decimals ('7.5', '-14.125', '0')."""
    text = f"{round(float(a), 3):.3f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def format_name(x, y, z):
    """File name for pose (x, y, z) in degrees, each rounded to 3 decimals."""
    return f"{format_angle(x)}_{format_angle(y)}_{format_angle(z)}.png"


def quantize(x, y, z):
    """The pose exactly as its file name will record it (3 decimals)."""
    return tuple(float(format_angle(a)) for a in (x, y, z))


def parse_name(path):
    """Pose (x, y, z) in degrees from a file name or path; BadName names the file if it does not match."""
    base = os.path.basename(str(path))
    m = _NAME_RE.match(base)
    if not m:
        raise BadName(f"{path}: file name is not <x>_<y>_<z>.png with decimal degrees "
                      f"(e.g. 12_-3_30.png, 7.5_3.25_-14.125.png)")
    return tuple(float(g) for g in m.groups())
