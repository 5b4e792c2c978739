"""Colours: the paper's four texture colours, and finding the palette of any texture image.

The paper (section 2.1) gives green as Lab (46, -52, 49) and blue as
Lab (30, 68, -112). Green is inside the sRGB gamut; blue is not (plain
clipping of lab2rgb gives (0, 36, 255), 8 CIEDE2000 units away), so each is
stored as the 8-bit sRGB colour nearest to the paper's Lab value in
CIEDE2000 (D65, found by an exhaustive search over the sRGB cube
neighbourhood; `tests/textures` checks the distances).

`find_palette` recovers the distinct colours of an image robustly enough for
textures people bring: antialiased edges (blends of two colours), JPEG noise
and near-duplicate shades. See docs/textures.md ("Palette").
"""
import numpy as np
from skimage.color import deltaE_ciede2000, rgb2lab

PAPER_LAB = {
    "white": (100.0, 0.0, 0.0),
    "black": (0.0, 0.0, 0.0),
    "green": (46.0, -52.0, 49.0),
    "blue": (30.0, 68.0, -112.0),
}

SRGB = {
    "white": (255, 255, 255),
    "black": (0, 0, 0),
    "green": (0, 128, 3),    # Lab (46.2, -51.6, 49.3): dE2000 0.3 from the paper's value
    "blue": (0, 38, 231),    # Lab (32.2, 63.3, -94.5): dE2000 4.7, nearest in gamut
}

# Palette search parameters (documented in docs/textures.md).
MAX_COLOURS = 8        # k-means starts with this many clusters
MERGE_DE2000 = 12.0    # clusters closer than this are one colour with noise
MIN_SHARE = 0.005      # clusters with fewer pixels than this are dropped
BLEND_DE76 = 12.0      # a cluster this close to the segment between two others may be a blend
BLEND_EDGE_FRAC = 0.6  # ... and is one if this share of its pixels touches another colour
CORE_DE76 = 20.0       # members this close to a centre define its final colour


def srgb8_to_lab(rgb):
    """Lab (D65) of 8-bit sRGB values, any leading shape, last axis 3."""
    rgb = np.asarray(rgb, dtype=np.float64) / 255.0
    shape = rgb.shape
    return rgb2lab(rgb.reshape(-1, 1, 3)).reshape(shape)


def delta_e2000(lab_a, lab_b):
    """CIEDE2000 colour difference between Lab colours (broadcasting)."""
    a = np.asarray(lab_a, dtype=np.float64)
    b = np.asarray(lab_b, dtype=np.float64)
    a, b = np.broadcast_arrays(a, b)
    return deltaE_ciede2000(a.reshape(-1, 1, 3), b.reshape(-1, 1, 3)).reshape(a.shape[:-1])


def _weighted_kmeans(x, w, k, rng, iters=40):
    """Lloyd k-means of points x [N,3] with weights w, k-means++ start. Returns centres [k,3]."""
    n = len(x)
    k = min(k, n)
    centres = [x[rng.choice(n, p=w / w.sum())]]
    d2 = ((x - centres[0]) ** 2).sum(1)
    for _ in range(1, k):
        p = w * d2
        if p.sum() <= 0:
            break
        centres.append(x[rng.choice(n, p=p / p.sum())])
        d2 = np.minimum(d2, ((x - centres[-1]) ** 2).sum(1))
    c = np.array(centres)
    for _ in range(iters):
        lab = _nearest(x, c)
        new = c.copy()
        for j in range(len(c)):
            m = lab == j
            if m.any():
                new[j] = np.average(x[m], axis=0, weights=w[m])
        if np.allclose(new, c, atol=1e-3):
            break
        c = new
    return c


def _nearest(x, c):
    """Index of the nearest centre (Euclidean Lab, i.e. dE76) for each point."""
    d = ((x[:, None, :] - c[None, :, :]) ** 2).sum(2)
    return d.argmin(1)


def _segment_distance(p, a, b):
    """Distance from p to segment ab and the position t in [0, 1] of the nearest point."""
    ab = b - a
    t = float(np.clip(np.dot(p - a, ab) / max(np.dot(ab, ab), 1e-12), 0.0, 1.0))
    return float(np.linalg.norm(p - (a + t * ab))), t


def _is_blend(centres, share, c):
    """True when colour c lies between two more common colours (a mix of them)."""
    others = [k for k in range(len(centres)) if k != c and share[k] > share[c]]
    for i, a in enumerate(others):
        for b in others[i + 1:]:
            dist, t = _segment_distance(centres[c], centres[a], centres[b])
            if dist < BLEND_DE76 and 0.05 < t < 0.95:
                return True
    return False


def _edge_fraction(labels, j):
    """Share of pixels labelled j that have a 4-neighbour with another label."""
    m = labels == j
    if not m.any():
        return 0.0
    other = np.zeros_like(m)
    other[1:, :] |= labels[:-1, :] != j
    other[:-1, :] |= labels[1:, :] != j
    other[:, 1:] |= labels[:, :-1] != j
    other[:, :-1] |= labels[:, 1:] != j
    return float((m & other).sum() / m.sum())


class Palette:
    """The distinct colours of an image: `lab` [K,3], `rgb` [K,3] 8-bit, `share` [K], `labels` [H,W]."""

    def __init__(self, lab, rgb, share, labels):
        self.lab, self.rgb, self.share, self.labels = lab, rgb, share, labels

    @property
    def blank(self):
        """Index of the blank (background) colour: the lightest palette colour (highest L*)."""
        return int(np.argmax(self.lab[:, 0]))


def find_palette(rgb, seed=0):
    """Palette of an 8-bit RGB image [H,W,3]: clustering in Lab, merging noise, dropping blends.

    1. Distinct pixel values with their counts; weighted k-means (k = 8) in Lab.
    2. Repeat until stable: merge the two closest clusters if dE2000 < 12;
       drop clusters holding < 0.5 % of the pixels; drop a cluster lying
       within dE76 12 of the segment between two other colours when 60 % or
       more of its pixels touch another colour (an antialiasing blend).
       Dropped pixels go to the nearest remaining colour.
    3. Each colour is the mean of its members within dE76 20 of the centre.
    """
    h, w, _ = rgb.shape
    packed = (rgb[..., 0].astype(np.int64) << 16) | (rgb[..., 1].astype(np.int64) << 8) | rgb[..., 2]
    uniq, inverse, counts = np.unique(packed.ravel(), return_inverse=True, return_counts=True)
    urgb = np.stack([(uniq >> 16) & 255, (uniq >> 8) & 255, uniq & 255], 1)
    ulab = srgb8_to_lab(urgb)
    weights = counts.astype(np.float64)
    rng = np.random.default_rng(seed)
    centres = _weighted_kmeans(ulab, weights, MAX_COLOURS, rng)
    while True:
        ulabels = _nearest(ulab, centres)
        share = np.bincount(ulabels, weights=weights, minlength=len(centres)) / weights.sum()
        if len(centres) > 1:
            # Merge near-duplicates (noise splitting one colour).
            de = delta_e2000(centres[:, None, :], centres[None, :, :])
            np.fill_diagonal(de, np.inf)
            i, j = np.unravel_index(np.argmin(de), de.shape)
            if de[i, j] < MERGE_DE2000:
                merged = (centres[i] * share[i] + centres[j] * share[j]) / max(share[i] + share[j], 1e-12)
                centres = np.delete(centres, j, 0)
                centres[i if i < j else i - 1] = merged
                continue
            # Drop rare clusters.
            small = np.argmin(share)
            if share[small] < MIN_SHARE:
                centres = np.delete(centres, small, 0)
                continue
            # Drop antialiasing blends: between two other colours and mostly on edges.
            labels = ulabels[inverse].reshape(h, w)
            dropped = False
            for c in np.argsort(share):
                if _is_blend(centres, share, c) and _edge_fraction(labels, c) >= BLEND_EDGE_FRAC:
                    centres = np.delete(centres, c, 0)
                    dropped = True
                    break
            if dropped:
                continue
        break
    # Final colours from the core members of each cluster.
    ulabels = _nearest(ulab, centres)
    lab = np.empty_like(centres)
    rgbs = []
    for j in range(len(centres)):
        m = ulabels == j
        core = m & (np.linalg.norm(ulab - centres[j], axis=1) < CORE_DE76)
        sel = core if core.any() else m
        lab[j] = np.average(ulab[sel], axis=0, weights=weights[sel]) if sel.any() else centres[j]
        rgb_j = np.average(urgb[sel], axis=0, weights=weights[sel]) if sel.any() else np.zeros(3)
        rgbs.append(rgb_j)
    ulabels = _nearest(ulab, lab)
    share = np.bincount(ulabels, weights=weights, minlength=len(lab)) / weights.sum()
    labels = ulabels[inverse].reshape(h, w).astype(np.uint8)
    return Palette(lab, np.rint(np.array(rgbs)).astype(int), share, labels)
