"""The paper's six textures, Texture_{1,2,3}_{bw,color}, as equirectangular PNGs.

Each design is a list of rectangles in (latitude, longitude) degrees drawn in
order onto a white sphere (conventions.md texture mapping: row 0 is the north
pole = body +Y, column 0 is longitude -180). No randomness: the layouts are
tables below, so every run writes the same bytes.

Design rules (paper section 3.3, measured by `textures check`):
- stripe spacing ratio eta = d / (2 pi r) >= 5 %: neighbouring stripes are
  at least 18 degrees apart centre to centre (21 degrees here) along every
  meridian and every latitude ring;
- texture : blank area close to 1 : 1 in image pixels (and on the sphere);
- colours black, white, green, blue, every pair dE2000 > 30;
- orientation uniqueness over the P1 range (each axis +-30 degrees).

Texture 1 is "horizontal stripes only". Full latitude circles would be
invariant under rotation about the pole (body Y): the camera would see the
same image for every body-Y angle, poses (0, y, z) for all y would look alike
and Y could not be measured at all. The paper's Texture 1 still reached
about 0.66 degrees Y error, like its Textures 2 and 3, so its stripes cannot
have been full circles. Ours are horizontal stripes broken by gaps at
different longitudes on each stripe: still only horizontal stripes, but the
stripe ends mark the longitude, so the checker's uniqueness criterion passes
(with the smallest margin of the three levels: Y steps only move the ends).
The deliberately symmetric variant (unbroken bands) is what the tests use
to show the uniqueness criterion failing.

Texture 2 keeps Texture 1's stripes (narrower, to keep the area ratio) and
adds column stripes (meridian segments) running from the centre line of one
stripe row to another. Texture 3 adds more column stripes, and two of its
stripe rows are cut into short horizontal stripes hanging off the columns.

Measured (docs/textures.md): eta 5.8 %, ink 49 % of the pixels, uniqueness
U = 0.32 / 0.35 (Texture 1 bw / color), 0.55 / 0.70 (2), 0.70 / 0.74 (3)
against the pass mark 0.15; the unbroken bands give U = 0.

The bw and color versions of a level share one layout: each rectangle has a
colour slot (black, green or blue); bw paints every slot black.
"""
import os

import numpy as np
from PIL import Image

from textures.palette import SRGB

WIDTH, HEIGHT = 2048, 1024
LEVELS = (1, 2, 3)
VERSIONS = ("bw", "color")

BLACK, GREEN, BLUE = 1, 2, 3       # colour slots; 0 is the white background
SLOT_RGB = {0: SRGB["white"], BLACK: SRGB["black"], GREEN: SRGB["green"], BLUE: SRGB["blue"]}

STRIPE_LATS = (73.5, 52.5, 31.5, 10.5, -10.5, -31.5, -52.5, -73.5)   # 21 degrees apart
STRIPE_SLOTS = (BLACK, GREEN, BLUE, BLACK, GREEN, BLUE, BLACK, GREEN)
# Gaps (longitude ranges, degrees) in each horizontal stripe, top to bottom:
# their ends sit at different longitudes on every stripe.
STRIPE_GAPS = (
    ((-100, -60), (95, 135)),
    ((-170, -135), (20, 55)),
    ((-45, -15), (140, 170)),
    ((-150, -120), (60, 90)),
    ((-85, -55), (110, 140)),
    ((-135, -100), (5, 35)),
    ((-30, 0), (125, 160)),
    ((-175, -150), (40, 80)),
)

# Column stripes: (longitude centre, first stripe row index, last stripe row index, slot).
# A column runs from the centre of one horizontal stripe to the centre of another.
COLUMNS_2 = (
    (-152, 1, 4, BLUE),
    (-97, 3, 6, GREEN),
    (-38, 0, 3, BLACK),
    (14, 2, 6, BLUE),
    (68, 1, 5, GREEN),
    (121, 3, 7, BLACK),
)
COLUMNS_3 = COLUMNS_2 + (
    (-125, 4, 7, BLUE),
    (-68, 0, 2, BLUE),
    (-12, 4, 7, BLUE),
    (40, 0, 3, BLACK),
    (95, 5, 7, BLUE),
    (150, 0, 4, GREEN),
)
# Texture 3: these stripe rows are not long stripes but short horizontal
# stripes, each (row index, longitude start, longitude end, slot).
SHORT_ROWS_3 = (2, 5)
SHORT_3 = (
    (2, -152, -122, BLUE), (2, -68, -40, BLACK), (2, 14, 40, BLUE), (2, 95, 121, GREEN),
    (2, 150, 175, BLUE),
    (5, -125, -97, BLUE), (5, -38, -12, GREEN), (5, 40, 68, BLUE), (5, 121, 150, BLUE),
    (5, -180, -160, BLACK),
)

STRIPE_WIDTH = {1: 13.5, 2: 12.5, 3: 13.0}   # degrees of latitude
COLUMN_WIDTH = {2: 10.0, 3: 12.0}             # degrees of longitude


def _hstripe_rects(lat, width, gaps, slot):
    """Rectangles (lat0, lat1, lon0, lon1, slot) of one horizontal stripe minus its gaps."""
    edges = sorted(gaps)
    rects, start = [], -180.0
    for g0, g1 in edges:
        if g0 > start:
            rects.append((lat - width / 2, lat + width / 2, start, g0, slot))
        start = g1
    if start < 180.0:
        rects.append((lat - width / 2, lat + width / 2, start, 180.0, slot))
    return rects


def layout(level):
    """The rectangles of Texture `level` (1, 2 or 3), in drawing order."""
    if level not in LEVELS:
        raise ValueError(f"texture level {level!r}: choose one of {LEVELS}")
    w = STRIPE_WIDTH[level]
    rects = []
    for i, (lat, gaps, slot) in enumerate(zip(STRIPE_LATS, STRIPE_GAPS, STRIPE_SLOTS)):
        if level == 3 and i in SHORT_ROWS_3:
            continue
        rects += _hstripe_rects(lat, w, gaps, slot)
    if level == 3:
        for i, lon0, lon1, slot in SHORT_3:
            lat = STRIPE_LATS[i]
            rects.append((lat - w / 2, lat + w / 2, lon0, lon1, slot))
    if level >= 2:
        cw = COLUMN_WIDTH[level]
        for lon, i0, i1, slot in (COLUMNS_2 if level == 2 else COLUMNS_3):
            lat_a, lat_b = STRIPE_LATS[i0], STRIPE_LATS[i1]
            rects.append((min(lat_a, lat_b), max(lat_a, lat_b), lon - cw / 2, lon + cw / 2, slot))
    return rects


def rasterize(rects, width=WIDTH, height=HEIGHT):
    """Slot image [height, width] (uint8) of rectangles in degrees; pixel edges rounded to the nearest."""
    if width != 2 * height:
        raise ValueError(f"width {width} must be twice the height {height}")
    img = np.zeros((height, width), np.uint8)
    for lat0, lat1, lon0, lon1, slot in rects:
        r0 = int(round((90.0 - lat1) / 180.0 * height))
        r1 = int(round((90.0 - lat0) / 180.0 * height))
        c0 = int(round((lon0 + 180.0) / 360.0 * width))
        c1 = int(round((lon1 + 180.0) / 360.0 * width))
        cols = np.arange(c0, c1) % width   # longitudes wrap at +-180
        img[max(r0, 0):min(r1, height), cols] = slot
    return img


def render(level, version, width=WIDTH, height=HEIGHT):
    """RGB image [height, width, 3] uint8 of Texture_<level>_<version>."""
    if version not in VERSIONS:
        raise ValueError(f"texture version {version!r}: choose one of {VERSIONS}")
    slots = rasterize(layout(level), width, height)
    if version == "bw":
        slots = np.where(slots > 0, BLACK, 0).astype(np.uint8)
    lut = np.array([SLOT_RGB[k] for k in range(4)], np.uint8)
    return lut[slots]


def texture_name(level, version):
    """File stem of a paper texture, e.g. Texture_3_color."""
    return f"Texture_{level}_{version}"


def write_png_atomic(rgb, path):
    """Write an RGB array as PNG through a temporary name and a rename (never half a file)."""
    tmp = f"{path}.tmp{os.getpid()}.png"
    try:
        Image.fromarray(rgb, "RGB").save(tmp, format="PNG", optimize=False)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def generate_all(out_dir, width=WIDTH, height=HEIGHT):
    """Write the six textures into out_dir; returns their paths."""
    os.makedirs(out_dir, exist_ok=True)
    paths = []
    for level in LEVELS:
        for version in VERSIONS:
            path = os.path.join(out_dir, texture_name(level, version) + ".png")
            write_png_atomic(render(level, version, width, height), path)
            paths.append(path)
    return paths
