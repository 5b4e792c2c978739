"""Fast numpy views of a textured sphere, and the orientation-uniqueness scan.

A view is a low-resolution orthographic image of the visible hemisphere
(the camera on +Z_W looking toward -Z_W, image right +X_W, up +Y_W), in Lab
colour, without shading: exactly what distinguishes one pose from another
for the texture itself. Rotations come from `sim.pose.euler_to_matrix`; the
texture lookup follows conventions.md (lat = asin(dy), lon = atan2(dx, dz)).

Uniqueness (docs/textures.md, "Orientation uniqueness"):
- poses: the P1 grid, each axis in [-30, 30] degrees on a 3 degree grid
  (21^3 = 9261 poses);
- D(p, q): RMS over the view disc of the Lab difference (dE76) of the two
  views;
- step: the median of D over all pairs of grid neighbours (one axis +-3
  degrees), the typical view change of a 3 degree step;
- U = min D(p, q) / step over all pairs at least 3 degrees apart
  (geodesic), with the pair named. U < 0.15 fails: somewhere two poses 3 or
  more degrees apart look more alike than 15 % of a typical 3 degree step.
  The far variant (pairs >= 9 degrees apart) is reported beside it: it shows
  global twins (symmetries) rather than locally weak steps.

The 43 million pairs are not all measured in full: views are projected on
their first PCA_DIMS principal components, each pose's CANDIDATES nearest
poses in that projection (among those far enough away) and every pair of
grid neighbours are measured exactly, and the smallest of those is reported.
Exact twins project to the same point, so symmetries are always found; a
test checks the search against brute force on a coarse grid.
"""
import numpy as np
from tqdm import tqdm

from sim.pose import euler_to_matrix, geodesic_deg

VIEW_PX = 32           # view image side in pixels
DISC_FRAC = 0.95       # pixels within this fraction of the radius (grazing limb left out)
TEX_MAX_WIDTH = 4096   # wider textures are reduced by a whole factor (memory); narrower ones stay as they are
MIN_SEP_DEG = 3.0      # pairs at least this far apart (geodesic) are compared
FAR_SEP_DEG = 9.0      # ... and the "far" variant
SEP_TOL_DEG = 0.05     # grid pairs one step apart may be a hair under 3 degrees
U_THRESHOLD = 0.15     # pass when U >= this
PCA_DIMS = 64
CANDIDATES = 4


def lonlat_from_direction(d):
    """(lat, lon) in degrees of body directions d [..., 3] (inverse of sim.pose.body_direction)."""
    d = np.asarray(d, dtype=np.float64)
    lat = np.degrees(np.arcsin(np.clip(d[..., 1], -1.0, 1.0)))
    lon = np.degrees(np.arctan2(d[..., 0], d[..., 2]))
    return lat, lon


def view_points(size=VIEW_PX, disc_frac=DISC_FRAC):
    """World points [N, 3] on the unit sphere seen by the orthographic view's pixel centres."""
    c = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    x, y = np.meshgrid(c, -c)        # row 0 is the top of the image: +Y_W
    r2 = x * x + y * y
    m = r2 < disc_frac ** 2
    z = np.sqrt(1.0 - r2[m])
    return np.stack([x[m], y[m], z], 1), m


def sample_texture(tex, lat, lon):
    """Bilinear lookup of texture tex [h, w, C] at (lat, lon) degrees; longitude wraps."""
    h, w = tex.shape[:2]
    u = (lon + 180.0) / 360.0 * w - 0.5
    v = (90.0 - lat) / 180.0 * h - 0.5
    u0 = np.floor(u).astype(np.int64)
    v0 = np.floor(v).astype(np.int64)
    fu = (u - u0)[..., None]
    fv = (v - v0)[..., None]
    u0m, u1m = u0 % w, (u0 + 1) % w
    v0c, v1c = np.clip(v0, 0, h - 1), np.clip(v0 + 1, 0, h - 1)
    top = tex[v0c, u0m] * (1 - fu) + tex[v0c, u1m] * fu
    bot = tex[v1c, u0m] * (1 - fu) + tex[v1c, u1m] * fu
    return top * (1 - fv) + bot * fv


def _box_wrap(a, k):
    """Mean over k (odd) neighbouring columns of a [rows, w], wrapping around (longitude)."""
    m = k // 2
    if m == 0:
        return a
    p = np.concatenate([a[:, -m:], a, a[:, :m]], 1)
    c = np.concatenate([np.zeros((len(a), 1)), np.cumsum(p, 1)], 1)
    return (c[:, k:] - c[:, :-k]) / k


def _box_clamp(a, k):
    """Mean over k (odd) neighbouring rows of a [h, w], the edge rows repeated (poles)."""
    m = k // 2
    if m == 0:
        return a
    p = np.concatenate([np.repeat(a[:1], m, 0), a, np.repeat(a[-1:], m, 0)], 0)
    c = np.concatenate([np.zeros((1, a.shape[1])), np.cumsum(p, 0)], 0)
    return (c[k:] - c[:-k]) / k


def _odd(x, cap):
    """Nearest odd whole number to x, at least 1 and at most cap (itself odd)."""
    return int(min(cap, max(1, 2 * int(np.floor(x / 2.0)) + 1)))


def _xyz_of_srgb8(rgb):
    """CIE XYZ (D65), float32, of 8-bit sRGB values: skimage's rgb2xyz (same curve, same matrix)
    through a 256-entry table of linear light."""
    from skimage.color.colorconv import xyz_from_rgb
    v = np.arange(256) / 255.0
    lin = np.where(v > 0.04045, ((v + 0.055) / 1.055) ** 2.4, v / 12.92).astype(np.float32)
    return lin[rgb] @ xyz_from_rgb.T.astype(np.float32)


def camera_texture(rgb, size=VIEW_PX):
    """Lab texture [h, w, 3] float32 of an sRGB uint8 texture as view pixels of `size` see it.

    A camera pixel integrates light: every texel becomes the mean, in linear
    light (CIE XYZ), over a box the size of one view pixel at the disc centre
    (2 / size radians of arc), stretched by 1 / cos(latitude) along the ring
    so that it covers the same arc on the sphere; then Lab. The boxes are whole
    texels, centred, and wrap in longitude, so a longitude period of whole
    texels survives exactly (twins stay twins, U = 0). Textures wider than
    TEX_MAX_WIDTH are first averaged over f x f blocks (f the smallest whole
    factor that fits). Rows are converted in chunks, so memory stays near a
    few float32 copies of the (reduced) texture.
    """
    from skimage.color import xyz2lab
    h, w = rgb.shape[:2]
    f = int(np.ceil(w / TEX_MAX_WIDTH))
    hr, wr = h // f, w // f
    if h % f == 0 and w % f == 0:
        xyz = np.empty((hr, wr, 3), np.float32)
        step = max(1, 256 // f) * f
        for r0 in range(0, h, step):
            chunk = _xyz_of_srgb8(rgb[r0:r0 + step])
            n = chunk.shape[0] // f
            xyz[r0 // f:r0 // f + n] = chunk.reshape(n, f, wr, f, 3).mean((1, 3)) if f > 1 else chunk
    else:   # no whole factor fits: area resampling (a period then survives only approximately)
        import cv2
        xyz = cv2.resize(_xyz_of_srgb8(rgb), (wr, hr), interpolation=cv2.INTER_AREA)
    h, w = hr, wr
    pitch = np.degrees(2.0 / size)                     # view pixel footprint at the disc centre, degrees
    lat = 90.0 - (np.arange(h) + 0.5) / h * 180.0
    k_lat = _odd(pitch / (180.0 / h), h if h % 2 else h - 1)
    k_lon = np.array([_odd(pitch / max(np.cos(np.radians(la)), 1e-6) / (360.0 / w), w if w % 2 else w - 1)
                      for la in lat])
    for c in range(3):
        ch = xyz[..., c].astype(np.float64)
        rows = np.empty_like(ch)
        for k in np.unique(k_lon):
            sel = k_lon == k
            rows[sel] = _box_wrap(ch[sel], k)
        xyz[..., c] = _box_clamp(rows, k_lat)
    np.clip(xyz, 0.0, None, out=xyz)
    lab = np.empty_like(xyz)
    for r0 in range(0, h, 256):
        lab[r0:r0 + 256] = xyz2lab(xyz[r0:r0 + 256].astype(np.float64))
    return lab


def pose_grid(limit=30.0, step=3.0):
    """All poses (x, y, z) with each angle in [-limit, limit] on the step grid, [P, 3]."""
    a = np.arange(-limit, limit + 1e-9, step)
    g = np.stack(np.meshgrid(a, a, a, indexing="ij"), -1).reshape(-1, 3)
    return g


def rotations(poses):
    """Body-to-world matrices [P, 3, 3] from sim.pose.euler_to_matrix."""
    return np.stack([euler_to_matrix(*p) for p in poses])


def render_views(tex_lab, poses, size=VIEW_PX, progress=None):
    """Views [P, N*3] float32 (Lab per disc pixel) of texture tex_lab at each pose."""
    pts, _ = view_points(size)
    Rs = rotations(poses)
    out = np.empty((len(poses), pts.shape[0] * 3), np.float32)
    chunk = 256
    for s in range(0, len(poses), chunk):
        R = Rs[s:s + chunk]
        d = np.einsum("pji,nj->pni", R, pts)          # body direction = R^T p_W
        lat, lon = lonlat_from_direction(d)
        out[s:s + chunk] = sample_texture(tex_lab, lat, lon).reshape(len(R), -1)
        if progress is not None:
            progress.update(len(R))
    return out


def _rms(a, b):
    """RMS over pixels of the Lab difference (dE76) between view rows a [M, N*3] and b [M, N*3]."""
    d = a - b
    return np.sqrt(np.einsum("ij,ij->i", d, d) / (a.shape[1] // 3))


def neighbour_steps(views, n_axis):
    """D between every grid pose and its next neighbour on each axis (poses in pose_grid order).

    Returns (distances [M], pairs [M, 2] of pose indices).
    """
    idx = np.arange(n_axis ** 3).reshape(n_axis, n_axis, n_axis)
    ia, ib = [], []
    for ax in range(3):
        ia.append(np.take(idx, np.arange(n_axis - 1), axis=ax).ravel())
        ib.append(np.take(idx, np.arange(1, n_axis), axis=ax).ravel())
    pairs = np.stack([np.concatenate(ia), np.concatenate(ib)], 1)
    return _exact(views, pairs), pairs


def _exact(views, pairs):
    """Exact RMS distances for index pairs [M, 2], in chunks."""
    out = np.empty(len(pairs), np.float64)
    for s in range(0, len(pairs), 2048):
        p = pairs[s:s + 2048]
        out[s:s + 2048] = _rms(views[p[:, 0]], views[p[:, 1]])
    return out


def _pca_basis(views, dims, rng):
    """Orthonormal basis [F, dims] of the leading principal components of a subsample of views."""
    sub = views[rng.choice(len(views), size=min(len(views), 400), replace=False)]
    mean = views.mean(0)
    sub = (sub - mean).astype(np.float64)
    lam, vec = np.linalg.eigh(sub @ sub.T)          # small Gram matrix instead of a large SVD
    order = np.argsort(lam)[::-1][:dims]
    lam, vec = lam[order], vec[:, order]
    keep = lam > lam[0] * 1e-9
    basis = sub.T @ (vec[:, keep] / np.sqrt(lam[keep]))
    basis, _ = np.linalg.qr(basis)
    return mean, basis.astype(np.float32)


def closest_pairs(views, Rs, seps, progress=None, chunk=1024):
    """Smallest RMS view distance over pairs at least sep degrees apart, for each sep in seps.

    Candidates: each pose's CANDIDATES nearest poses (at least sep apart) in
    a PCA_DIMS-component projection of the views; every candidate is then
    measured exactly at full dimension. Returns {sep: (distance, i, j)}.
    """
    n = len(views)
    npix = views.shape[1] // 3
    mean, basis = _pca_basis(views, PCA_DIMS, np.random.default_rng(0))
    proj = (views - mean) @ basis
    sq = np.einsum("ij,ij->i", proj, proj)
    flat = Rs.reshape(n, 9).astype(np.float32)
    # trace(Ra^T Rb) = 1 + 2 cos(angle): pairs closer than sep have a larger trace.
    tr_max = {s: np.float32(1.0 + 2.0 * np.cos(np.radians(s - SEP_TOL_DEG))) for s in seps}
    cand = {s: [] for s in seps}
    k = min(CANDIDATES, n - 1)
    for s0 in range(0, n, chunk):
        rows = np.arange(s0, min(n, s0 + chunk))
        d2 = (sq[rows, None] + sq[None, :] - 2.0 * (proj[rows] @ proj.T)) / npix
        tr = flat[rows] @ flat.T
        for s in seps:
            m = np.where(tr <= tr_max[s], d2, np.float32(np.inf))
            j = np.argpartition(m, k, axis=1)[:, :k]
            ok = np.isfinite(np.take_along_axis(m, j, 1))
            cand[s].append(np.stack([np.broadcast_to(rows[:, None], j.shape)[ok], j[ok]], 1))
        if progress is not None:
            progress.update(len(rows))
    out = {}
    for s in seps:
        pairs = np.unique(np.sort(np.concatenate(cand[s]), axis=1), axis=0)
        if len(pairs) == 0:
            out[s] = (np.inf, -1, -1)
            continue
        dist = _exact(views, pairs)
        b = int(np.argmin(dist))
        out[s] = (float(dist[b]), int(pairs[b, 0]), int(pairs[b, 1]))
    return out


def uniqueness(tex_lab, limit=30.0, step=3.0, size=VIEW_PX, progress=True):
    """Orientation-uniqueness scan of a Lab texture; returns a dict (see module docstring)."""
    poses = pose_grid(limit, step)
    bar = tqdm(total=2 * len(poses), desc="uniqueness scan", unit="pose",
               disable=(None if progress else True), leave=False)
    try:
        views = render_views(tex_lab, poses, size, bar)
        Rs = rotations(poses)
        n_axis = int(round(len(poses) ** (1 / 3)))
        steps, step_pairs = neighbour_steps(views, n_axis)
        closest = closest_pairs(views, Rs, (MIN_SEP_DEG, FAR_SEP_DEG), bar)
        # Grid neighbours are pairs one step apart: measured exactly, they join the near search.
        b = int(np.argmin(steps))
        if steps[b] <= closest[MIN_SEP_DEG][0]:     # ties: name the neighbouring pair
            closest[MIN_SEP_DEG] = (float(steps[b]), int(step_pairs[b, 0]), int(step_pairs[b, 1]))
    finally:
        bar.close()
    ref = float(np.median(steps))
    out = {"poses": len(poses), "grid_step_deg": step, "range_deg": limit,
           "view_px": size, "step_median_de": ref, "step_min_de": float(steps.min())}
    for key, sep in (("near", MIN_SEP_DEG), ("far", FAR_SEP_DEG)):
        d, i, j = closest[sep]
        out[key] = {
            "min_sep_deg": sep,
            "distance_de": d,
            "ratio": d / ref if ref > 0 else 0.0,
            "pose_a": [float(v) for v in poses[i]],
            "pose_b": [float(v) for v in poses[j]],
            "geodesic_deg": geodesic_deg(Rs[i], Rs[j]),
        }
    out["U"] = out["near"]["ratio"]
    out["threshold"] = U_THRESHOLD
    out["pass"] = bool(out["U"] >= U_THRESHOLD)
    return out
