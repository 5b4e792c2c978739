"""The paper's texture design criteria (section 3.3), measured on a texture image.

Each check returns a dict: id (stable key for machines), name, value (the measured number), unit,
requirement (text), passed (True, False, or None for reported-only values)
and details. docs/textures.md describes every measurement; in short:

- stripe spacing ratio eta = d / (2 pi r): along latitude rings and along
  meridians of the equirectangular image, the centre-to-centre distance d
  between neighbouring ink stripes (runs of non-blank pixels, whatever their
  colour) over the circumference of that ring, 2 pi r (for a latitude ring
  its own circumference, so eta = delta-longitude / 360; for a meridian the
  great circle, so eta = delta-latitude / 360). The smallest over the image
  must be >= 5 %.
- area ratio: ink pixels : blank pixels, blank being the lightest palette
  colour; passes within 2 : 3 .. 3 : 2 (ink share 40 .. 60 %). The share on
  the sphere's surface (pixels weighted by cos latitude) is reported beside.
- colour difference: CIEDE2000 between every pair of palette colours > 30.
- Tamura coarseness, contrast, directionality: reported, no threshold.
- orientation uniqueness: textures.views.uniqueness.
"""
import cv2
import numpy as np

from textures import views
from textures.palette import delta_e2000, find_palette, srgb8_to_lab

ETA_MIN = 0.05
INK_SHARE_RANGE = (0.40, 0.60)
DE_MIN = 30.0
SCAN_ROWS = 256        # latitude rings scanned for eta
SCAN_COLS = 512        # meridians scanned for eta
TAMURA_WIDTH = 512     # Tamura features are computed at this width
PEAK_MIN_SHARE = 0.02  # a direction-histogram peak holds at least this share of the edge pixels


def _runs(ink):
    """Start indices and lengths of runs of True in a 1-D boolean array (not wrapping)."""
    d = np.diff(np.concatenate([[0], ink.astype(np.int8), [0]]))
    starts = np.nonzero(d == 1)[0]
    ends = np.nonzero(d == -1)[0]
    return starts, ends - starts


def _clean(line, noise):
    """Flip runs shorter than `noise` pixels (antialiasing and JPEG specks) to their neighbours' class."""
    if noise <= 1:
        return line
    line = line.copy()
    for value in (True, False):
        starts, lengths = _runs(line == value)
        for s, n in zip(starts, lengths):
            if n < noise and s > 0 and s + n < len(line):
                line[s:s + n] = not value
    return line


def _spacings(ink, wrap):
    """Centre-to-centre distances (pixels) between consecutive ink runs, with the centres' midpoints."""
    n = len(ink)
    if wrap and ink.all():
        return np.empty(0), np.empty(0)
    if wrap and ink[0] and ink[-1]:
        # Rotate so the line starts on blank; runs across the seam stay whole.
        shift = int(np.argmin(ink))
        ink = np.roll(ink, -shift)
    else:
        shift = 0
    starts, lengths = _runs(ink)
    if len(starts) < 2:
        return np.empty(0), np.empty(0)
    centres = starts + lengths / 2.0
    gaps = np.diff(centres)
    mids = (centres[:-1] + centres[1:]) / 2.0
    if wrap:
        gaps = np.append(gaps, centres[0] + n - centres[-1])
        mids = np.append(mids, (centres[-1] + centres[0] + n) / 2.0)
    return gaps, (mids + shift) % n


def stripe_spacing(ink):
    """eta check from the ink mask [H, W] (True where not blank)."""
    h, w = ink.shape
    noise = max(2, w // 1024)    # shorter runs are antialiasing or JPEG specks
    best = (np.inf, None)
    rows = np.unique(np.linspace(0, h - 1, min(h, SCAN_ROWS)).round().astype(int))
    cols = np.unique(np.linspace(0, w - 1, min(w, SCAN_COLS)).round().astype(int))
    for r in rows:
        gaps, mids = _spacings(_clean(ink[r], noise), wrap=True)
        if len(gaps):
            k = int(np.argmin(gaps))
            eta = gaps[k] / w      # delta-longitude / 360 degrees
            if eta < best[0]:
                lat = 90.0 - (r + 0.5) / h * 180.0
                lon = (mids[k] / w) * 360.0 - 180.0
                best = (eta, f"along the latitude ring {lat:.1f} deg near longitude {lon:.1f} deg")
    for c in cols:
        gaps, mids = _spacings(_clean(ink[:, c], noise), wrap=False)
        if len(gaps):
            k = int(np.argmin(gaps))
            eta = gaps[k] / (2.0 * h)   # delta-latitude / 360 degrees
            if eta < best[0]:
                lon = (c + 0.5) / w * 360.0 - 180.0
                lat = 90.0 - mids[k] / h * 180.0
                best = (eta, f"along the meridian {lon:.1f} deg near latitude {lat:.1f} deg")
    eta, where = best
    if not np.isfinite(eta):
        return {"id": "eta", "name": "stripe spacing ratio", "value": None, "unit": "%",
                "requirement": f">= {ETA_MIN * 100:.0f} %", "passed": False,
                "details": "no two stripes found on any ring or meridian"}
    return {"id": "eta", "name": "stripe spacing ratio", "value": round(eta * 100, 2), "unit": "%",
            "requirement": f">= {ETA_MIN * 100:.0f} %", "passed": bool(eta >= ETA_MIN),
            "details": f"smallest centre-to-centre stripe distance, {where}"}


def area_ratio(ink):
    """Texture : blank area check from the ink mask [H, W]."""
    h, _ = ink.shape
    share = float(ink.mean())
    lat = np.radians(90.0 - (np.arange(h) + 0.5) / h * 180.0)
    wts = np.cos(lat)
    sphere = float((ink.mean(1) * wts).sum() / wts.sum())
    ratio = share / max(1.0 - share, 1e-12)
    lo, hi = INK_SHARE_RANGE
    return {"id": "area_ratio", "name": "texture:blank area ratio", "value": round(ratio, 3), "unit": ":1",
            "requirement": f"ink share {lo * 100:.0f}..{hi * 100:.0f} % of pixels (1:1 +- tolerance)",
            "passed": bool(lo <= share <= hi),
            "details": f"ink {share * 100:.1f} % of image pixels, {sphere * 100:.1f} % of the sphere's surface"}


def colour_difference(pal):
    """Smallest CIEDE2000 difference over palette pairs."""
    k = len(pal.lab)
    names = [f"#{r:02x}{g:02x}{b:02x}" for r, g, b in pal.rgb]
    if k < 2:
        return {"id": "delta_e2000", "name": "colour difference dE2000", "value": None, "unit": "",
                "requirement": f"> {DE_MIN:.0f} for every pair", "passed": False,
                "details": "only one colour"}
    best = (np.inf, None)
    pairs = []
    for i in range(k):
        for j in range(i + 1, k):
            d = float(delta_e2000(pal.lab[i], pal.lab[j]))
            pairs.append(f"{names[i]}-{names[j]} {d:.1f}")
            if d < best[0]:
                best = (d, (names[i], names[j]))
    return {"id": "delta_e2000", "name": "colour difference dE2000", "value": round(best[0], 1), "unit": "",
            "requirement": f"> {DE_MIN:.0f} for every pair", "passed": bool(best[0] > DE_MIN),
            "details": f"smallest between {best[1][0]} and {best[1][1]}; all pairs: " + ", ".join(pairs)}


def tamura(gray):
    """Tamura coarseness (degrees), contrast and directionality (0..1) of a gray image (0..255)."""
    h, w = gray.shape
    g = gray.astype(np.float64)
    # Coarseness: the window size 2^k with the largest difference of neighbouring averages.
    best_e = np.zeros_like(g)
    best_s = np.ones_like(g)
    for k in range(1, 6):
        size = 2 ** k
        a = cv2.blur(g, (size, size), borderType=cv2.BORDER_REFLECT)
        half = size // 2
        eh = np.abs(np.roll(a, -half, 1) - np.roll(a, half, 1))   # longitude wraps
        ev = np.zeros_like(a)
        ev[half:h - half] = np.abs(a[2 * half:] - a[:h - 2 * half])
        e = np.maximum(eh, ev)
        better = e > best_e
        best_e[better] = e[better]
        best_s[better] = size
    coarseness = float(best_s.mean()) * 360.0 / w
    # Contrast: sigma / kurtosis^(1/4).
    sd = g.std()
    contrast = 0.0 if sd == 0 else float(sd / (((g - g.mean()) ** 4).mean() / sd ** 4) ** 0.25)
    # Directionality: sharpness of the histogram of edge directions around its peaks.
    gh = cv2.filter2D(g, -1, np.array([[-1, 0, 1]] * 3, np.float64), borderType=cv2.BORDER_REFLECT)
    gv = cv2.filter2D(g, -1, np.array([[-1, 0, 1]] * 3, np.float64).T, borderType=cv2.BORDER_REFLECT)
    mag = (np.abs(gh) + np.abs(gv)) / 2.0
    theta = np.mod(np.arctan2(gv, gh) + np.pi / 2, np.pi)
    sel = mag >= 12.0
    nb = 16
    if sel.sum() == 0:
        directionality = 0.0
    else:
        hist, _ = np.histogram(theta[sel], bins=nb, range=(0, np.pi))
        hist = hist / hist.sum()
        peaks = [i for i in range(nb) if hist[i] >= hist[i - 1] and hist[i] > hist[(i + 1) % nb]
                 and hist[i] >= PEAK_MIN_SHARE]
        centres = (np.arange(nb) + 0.5) * np.pi / nb
        # Each bin belongs to its nearest peak (circular in pi).
        dist = np.abs(centres[:, None] - centres[peaks][None, :])
        dist = np.minimum(dist, np.pi - dist)
        spread = (hist * dist.min(1) ** 2).sum()
        directionality = float(np.clip(1.0 - len(peaks) * spread / (np.pi ** 2 / 12.0), 0.0, 1.0))
    return coarseness, contrast, directionality


def tamura_checks(rgb):
    """Tamura features as reported-only checks."""
    h, w = rgb.shape[:2]
    if w > TAMURA_WIDTH:
        rgb = cv2.resize(rgb, (TAMURA_WIDTH, TAMURA_WIDTH // 2), interpolation=cv2.INTER_AREA)
    gray = srgb8_to_lab(rgb)[..., 0] * 2.55
    crs, con, dirn = tamura(gray)
    note = "reported, no threshold"
    return [
        {"id": "tamura_coarseness", "name": "Tamura coarseness", "value": round(crs, 2), "unit": "deg", "requirement": note,
         "passed": None, "details": "mean best window 2^k (k = 1..5) at width 512, in degrees of longitude"},
        {"id": "tamura_contrast", "name": "Tamura contrast", "value": round(con, 1), "unit": "", "requirement": note,
         "passed": None, "details": "sigma / kurtosis^(1/4) of L* scaled to 0..255"},
        {"id": "tamura_directionality", "name": "Tamura directionality", "value": round(dirn, 3), "unit": "", "requirement": note,
         "passed": None, "details": "1 - n_peaks * spread of edge directions around peaks / uniform spread"},
    ]


def uniqueness_check(rgb, step=3.0, progress=True):
    """Orientation uniqueness over the P1 range (textures.views)."""
    u = views.uniqueness(views.camera_texture(rgb), step=step, progress=progress)
    near, far = u["near"], u["far"]
    fmt = lambda p: "(" + ", ".join(f"{v:g}" for v in p) + ")"
    return {"id": "uniqueness", "name": "orientation uniqueness", "value": round(u["U"], 3), "unit": "x step",
            "requirement": f">= {u['threshold']:g} x the median {step:g} deg step",
            "passed": u["pass"],
            "details": (f"most alike poses >= {near['min_sep_deg']:g} deg apart: {fmt(near['pose_a'])} and "
                        f"{fmt(near['pose_b'])} ({near['geodesic_deg']:.1f} deg apart), view difference "
                        f"{near['distance_de']:.2f} dE vs median step {u['step_median_de']:.2f} dE; "
                        f">= {far['min_sep_deg']:g} deg apart: {fmt(far['pose_a'])} and {fmt(far['pose_b'])}, "
                        f"{far['ratio']:.3f} x step"),
            "scan": u}


def check_texture(rgb, step=3.0, progress=True, uniqueness=True):
    """All criteria for an RGB texture [H, W, 3] uint8; returns (checks, palette)."""
    pal = find_palette(rgb)
    ink = pal.labels != pal.blank
    checks = [stripe_spacing(ink), area_ratio(ink), colour_difference(pal)]
    checks += tamura_checks(rgb)
    if uniqueness:
        checks.append(uniqueness_check(rgb, step=step, progress=progress))
    return checks, pal
