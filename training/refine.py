"""Render-and-compare refinement and the confidence of a pose (the reference; host/libposeinfer/refine.c
implements the same steps in C and is tested against this file).

The model file carries its texture (metadata `spherepose.texture_png`). From the network's pose
and the sphere's circle in the (undistorted) frame, the texture is rendered analytically into the
frame's geometry, pixel by pixel inside the circle: the ray of the conventions' pinhole camera,
its intersection with the sphere, the body direction R^T n, a bilinear texture lookup. A
photometric model absorbs what light does to colour: per channel c,

    I_c(p) ~ T_c(p) * (a0 + a1 n_x + a2 n_y + a3 n_z)_c + b_c

(a gain with a first-order shading term, and an offset; solved by least squares at every step).
Levenberg-Marquardt steps over the rotation, the circle's centre and its radius then minimise
the squared difference, coarse to fine on a pyramid of the frame and the texture. The residual is
the fraction of the frame's variance inside the circle that the aligned texture does not explain
(0: perfect, 1: no relation). A colour frame also gets its colour ratio: the share of the frame's
variance off its main colour axis, over the same share of the fitted rendering (about 1 when the
sphere shows the texture's colours, near 0 for a gray sphere of the same pattern). With the pose
checked against the model's ranges they decide whether the answer is confident. docs/refine.md
gives the algorithm and the numbers.
"""
import base64
import json
import math

import numpy as np

META_TEXTURE = "spherepose.texture_png"
META_CONFIDENCE = "spherepose.confidence"

# The algorithm's parameters: one source, copied into host/libposeinfer/refine.h (a unit test compares).
LEVELS = 3            # frame and texture pyramid levels, coarse to fine (2x2 box reductions)
ITERS = (4, 2, 1)     # Levenberg-Marquardt steps per level, coarse to fine
STRIDES = (2, 3, 5)   # sample every STRIDE-th row and column of each level, coarse to fine
RHO_MAX = 0.92        # pixels used: centre within RHO_MAX * r of the circle's centre
CROP_PAD = 4.0        # the frame's crop: the circle's square grown by CROP_PAD pixels
TEXTURE_WIDTH = 1024  # texture width at the finest level (reduced from the model's by 2x2 boxes)
DAMPING = 1e-3        # Levenberg-Marquardt: the least lambda of lambda * diag(J^T J)
MAX_STEP_DEG = 3.0    # a step that rotates more than this is scaled down to it
REF_D_OVER_R = 12.5   # the reference camera's distance / sphere radius (250 mm / 20 mm)
LUMA = (0.114, 0.587, 0.299)  # B, G, R weights of a gray frame's texture (ITU-R BT.601, as OpenCV)
FD_STEP = 1e-3        # finite-difference step (pixels) of the tests' check of d n / d (cx, cy, r)

DEFAULT_CONFIDENCE = {"residual_max": 0.25, "range_margin_deg": 2.0, "colour_min": 0.0,
                      "converge_max_deg": 0.3}

# The convergence check (confidence; docs/refine.md): an answer whose start was far off is refined
# again from itself, since one pass of ITERS steps does not reach the minimum from several degrees
# away; it is confident only when a pass moves it at most converge_max_deg.
CHECK_PASSES = 4      # refinement passes at most, the first included
CHECK_PX = 2.0        # checked when the first pass moved the circle's centre or radius farther ...
CHECK_DEG = 2.5       # ... or the pose farther from the network's than this, and every gray frame

# The circle after refinement (docs/refine.md): the texture fixes the refined radius within 0.11 %
# (p99 on the ray-caster's rig frames), the localisation's edges within 0.2 %, and where the
# localisation's circle is off (a fit in another basin, an arc pulled onto a backdrop's edge) the
# two radii disagree. When a confident answer's refined radius differs from the localisation's by
# more than RIM_CHECK_PCT percent, the printed circle is the rim found from the refined circle
# (preprocess.rim_from; sphere-crop-v2 only). Of the 6 897 answered development frames of the
# ray-caster 22 circles enter the limits of 0.5 px and 0.5 % and none leaves (0.1 %: 24 and 0, but
# 1 leaves on held-out seeds 459-474; 0.3 %: 15 and 0); docs/bench/localise.md, "The circle after
# refinement".
RIM_CHECK_PCT = 0.2

# The printed centre, a confident answer's: the centre c of the localisation's circle (or of
# that rim's) and the refined centre f, each weighed by its covariance. c's, C, comes from its
# rims (preprocess.find_sphere's cov, or rim_from's); f's is taken as CENTRE_FUSE_PX^2 times the
# identity, so the printed centre is c + C (C + CENTRE_FUSE_PX^2 I)^-1 (f - c). Where rims lie all
# round, C is about 0.001-0.004 px^2 and the refined centre (0.17 px off at the median) moves the
# printed one by a few hundredths. Where two opposite arcs have none (a sphere past the frame's
# edge with the post below), C is large along that axis, and the refined centre, which the whole
# texture holds, leads there. The rims' errors are correlated, so C understates them.
# CENTRE_FUSE_PX is therefore smaller than the refined centre's own scatter: it was chosen among
# 0.06-0.14 on 5 998 development frames of the ray-caster (seeds 475-498), and the centre's p99
# moved from 0.32 to 0.27 px and the frames outside 0.5 px from 4 to 2; on 3 597 frames of seeds
# 499-510 from 0.31 to 0.26 px and from 3 to 0 (docs/bench/localise.md, "The centre weighed
# against the refined centre").
CENTRE_FUSE_PX = 0.1


# ---- texture --------------------------------------------------------------------------------

def texture_png_b64(path_or_bgr):
    """The metadata value: base64 of the texture's PNG (the file's bytes when given a path)."""
    if isinstance(path_or_bgr, (str, bytes)) or hasattr(path_or_bgr, "__fspath__"):
        with open(path_or_bgr, "rb") as f:
            data = f.read()
        if data[:8] != b"\x89PNG\r\n\x1a\n":
            raise ValueError(f"{path_or_bgr}: not a PNG file")
        _decode_png(data, str(path_or_bgr))
    else:
        import cv2
        ok, buf = cv2.imencode(".png", np.asarray(path_or_bgr, np.uint8))
        if not ok:
            raise ValueError("texture: cannot encode as PNG")
        data = buf.tobytes()
    return base64.b64encode(data).decode("ascii")


def _decode_png(data, source):
    import cv2
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if img is None:
        raise ValueError(f"{source}: cannot decode the texture PNG")
    h, w = img.shape[:2]
    if w != 2 * h or h < 8:
        raise ValueError(f"{source}: texture is {w}x{h}, expected width = 2 x height")
    if w % (TEXTURE_WIDTH >> (LEVELS - 1)) or w < TEXTURE_WIDTH:
        raise ValueError(f"{source}: texture width {w} must be a multiple of "
                         f"{TEXTURE_WIDTH >> (LEVELS - 1)} and at least {TEXTURE_WIDTH}")
    return img


def texture_from_b64(text, source=META_TEXTURE):
    """BGR uint8 texture from the metadata value."""
    try:
        data = base64.b64decode(text, validate=True)
    except ValueError as e:
        raise ValueError(f"{source}: not base64 ({e})") from None
    return _decode_png(data, source)


def reduce2(img):
    """2x2 box reduction in float64 (the C code sums the same four values in the same order)."""
    a = np.asarray(img, np.float64)
    h, w = a.shape[0] // 2 * 2, a.shape[1] // 2 * 2
    a = a[:h, :w]
    return ((a[0::2, 0::2] + a[0::2, 1::2]) + (a[1::2, 0::2] + a[1::2, 1::2])) * 0.25


def texture_pyramid(bgr):
    """[finest, ..., coarsest] float64 textures; the finest is TEXTURE_WIDTH wide."""
    t = np.asarray(bgr, np.float64)
    while t.shape[1] > TEXTURE_WIDTH:
        t = reduce2(t)
    pyr = [t]
    for _ in range(LEVELS - 1):
        pyr.append(reduce2(pyr[-1]))
    return pyr


# ---- geometry ---------------------------------------------------------------------------------

def focal_px(r, camera_focal_px=None):
    """Focal length in pixels: the camera file's, else the one that puts the sphere at the
    reference camera's distance/radius ratio for a circle of radius r."""
    if camera_focal_px:
        return float(camera_focal_px)
    return r * math.sqrt(REF_D_OVER_R ** 2 - 1.0)


def normals(us, vs, cx, cy, r, f):
    """World-frame unit normals [N, 3] of the sphere points seen through pixels (us, vs)
    (continuous coordinates), the sphere's image a circle (cx, cy, r), focal length f px.
    The camera looks at the sphere's centre; the sphere has unit radius."""
    x = (us - cx) / f
    y = -(vs - cy) / f
    tan_a = r / f
    dist = math.sqrt(1.0 + tan_a * tan_a) / tan_a       # 1 / sin(alpha)
    inv = 1.0 / np.sqrt(x * x + y * y + 1.0)
    dx, dy, dz = x * inv, y * inv, -inv
    od = dist * dz                                       # O . d, O = (0, 0, dist)
    disc = np.maximum(od * od - dist * dist + 1.0, 0.0)
    t = -od - np.sqrt(disc)
    return np.stack([t * dx, t * dy, dist + t * dz], axis=1)


def normals_and_derivs(us, vs, cx, cy, r, fixed_f):
    """normals() and their derivatives [3, N, 3] with respect to (cx, cy, r); f follows r when
    no camera focal length is given. Differentiating |O + t d| = 1: for a change dO, dd of the
    camera centre and the ray, dt = -(n.dO + t n.dd) / (n.d) and dn = dO + dt d + t dd."""
    f = focal_px(r, fixed_f)
    x = (us - cx) / f
    y = -(vs - cy) / f
    tan_a = r / f
    sec = math.sqrt(1.0 + tan_a * tan_a)
    dist = sec / tan_a
    L = np.sqrt(x * x + y * y + 1.0)
    inv = 1.0 / L
    d = np.stack([x * inv, y * inv, -inv], axis=1)
    od = dist * d[:, 2]
    t = -od - np.sqrt(np.maximum(od * od - dist * dist + 1.0, 0.0))
    n = t[:, None] * d
    n[:, 2] += dist
    zero = np.zeros_like(x)
    if fixed_f:   # r moves the camera away: d dist / d r, the rays stay
        dq_r = np.stack([zero, zero, zero], axis=1)
        dD_r = -(1.0 / f) / (tan_a * tan_a * sec)
    else:         # f scales with r: the rays move, the distance stays
        dq_r = np.stack([-x / r, -y / r, zero], axis=1)
        dD_r = 0.0
    out = []
    for dq, dD in ((np.stack([zero - 1.0 / f, zero, zero], axis=1), 0.0),
                   (np.stack([zero, zero + 1.0 / f, zero], axis=1), 0.0),
                   (dq_r, dD_r)):
        dd = (dq - d * (d * dq).sum(axis=1, keepdims=True)) * inv[:, None]
        ndd = (n * dd).sum(axis=1)
        dt = -(n[:, 2] * dD + t * ndd) / (n * d).sum(axis=1)
        dn = dt[:, None] * d + t[:, None] * dd
        dn[:, 2] += dD
        out.append(dn)
    return n, np.stack(out)


def normals_and_derivs_fd(us, vs, cx, cy, r, fixed_f, h=FD_STEP):
    """The same derivatives by central differences (a check of the analytic ones)."""
    def n_at(cx_, cy_, r_):
        return normals(us, vs, cx_, cy_, r_, focal_px(r_, fixed_f))
    return n_at(cx, cy, r), np.stack([(n_at(cx + h, cy, r) - n_at(cx - h, cy, r)) / (2 * h),
                                      (n_at(cx, cy + h, r) - n_at(cx, cy - h, r)) / (2 * h),
                                      (n_at(cx, cy, r + h) - n_at(cx, cy, r - h)) / (2 * h)])


def sample(tex, b):
    """Bilinear texture values [N, 3] at body directions b [N, 3] and their gradients
    d value / d b [N, 3 (channel), 3] along the sphere."""
    h, w = tex.shape[:2]
    bx, by, bz = b[:, 0], b[:, 1], b[:, 2]
    rho2 = np.maximum(bx * bx + bz * bz, 1e-12)
    rho = np.sqrt(rho2)
    lon = np.arctan2(bx, bz)
    lat = np.arcsin(np.clip(by, -1.0, 1.0))
    ut = (lon + math.pi) * (w / (2 * math.pi)) - 0.5
    vt = (math.pi / 2 - lat) * (h / math.pi) - 0.5
    i0 = np.floor(ut)
    j0 = np.floor(vt)
    fx = (ut - i0)[:, None]
    fy = (vt - j0)[:, None]
    i0 = i0.astype(np.int64) % w
    i1 = (i0 + 1) % w
    j0 = j0.astype(np.int64)
    j1 = np.clip(j0 + 1, 0, h - 1)
    j0 = np.clip(j0, 0, h - 1)
    t00, t10, t01, t11 = tex[j0, i0], tex[j0, i1], tex[j1, i0], tex[j1, i1]
    top = t00 + fx * (t10 - t00)
    bot = t01 + fx * (t11 - t01)
    val = top + fy * (bot - top)
    du = (t10 - t00) + fy * ((t11 - t01) - (t10 - t00))      # d val / d ut
    dv = bot - top                                           # d val / d vt
    # d ut / d b and d vt / d b (tangent directions only matter)
    kw = w / (2 * math.pi)
    kh = -h / math.pi
    dut = np.stack([bz / rho2 * kw, np.zeros_like(bx), -bx / rho2 * kw], axis=1)
    dvt = np.stack([np.zeros_like(bx), kh / rho, np.zeros_like(bx)], axis=1)
    grad = du[:, :, None] * dut[:, None, :] + dv[:, :, None] * dvt[:, None, :]
    return val, grad


def euler_to_matrix(euler_deg):
    """(x, y, z) degrees -> body-to-world R = Rz(z) Ry(y) Rx(x) (float64 numpy)."""
    x, y, z = (math.radians(a) for a in euler_deg)
    cx, sx, cy, sy, cz, sz = math.cos(x), math.sin(x), math.cos(y), math.sin(y), math.cos(z), math.sin(z)
    return np.array([[cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx],
                     [sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx],
                     [-sy, cy * sx, cy * cx]])


def matrix_to_euler(R):
    """R -> (x, y, z) degrees (conventions.md, |y| < 90)."""
    y = -math.asin(max(-1.0, min(1.0, R[2, 0])))
    x = math.atan2(R[2, 1], R[2, 2])
    z = math.atan2(R[1, 0], R[0, 0])
    return (math.degrees(x), math.degrees(y), math.degrees(z))


def rotvec_to_matrix(w):
    """Rodrigues: rotation by |w| radians about w."""
    th = math.sqrt(float(w @ w))
    if th < 1e-15:
        return np.eye(3)
    k = w / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * (K @ K)


# ---- frame sampling ---------------------------------------------------------------------------

def frame_pyramid(frame, cx, cy, r):
    """[(image float64, scale)] finest first: the square around the circle (with room for the
    centre and radius to move) and its 2x2 reductions. Coordinates: continuous pixel
    coordinates of the level, origin at the crop's corner; scale: level pixels per frame pixel."""
    h, w = frame.shape[:2]
    half = r + CROP_PAD
    step = 1 << (LEVELS - 1)
    x0 = max(0, int(math.floor((cx - half) / step)) * step)
    y0 = max(0, int(math.floor((cy - half) / step)) * step)
    x1 = min(w, int(math.ceil((cx + half) / step)) * step)
    y1 = min(h, int(math.ceil((cy + half) / step)) * step)
    crop = np.asarray(frame[y0:y1, x0:x1])
    if crop.ndim == 2:
        crop = np.repeat(crop[:, :, None], 3, axis=2)
    crop = crop[:, :, :3]
    # a gray frame (one channel, or three equal ones): the texture is seen as its luma
    gray = bool((crop[:, :, 0] == crop[:, :, 1]).all() and (crop[:, :, 1] == crop[:, :, 2]).all())
    pyr = [crop.astype(np.float64)]
    for _ in range(LEVELS - 1):
        pyr.append(reduce2(pyr[-1]))
    return pyr, (x0, y0), gray


def pixel_set(img, cx, cy, r, stride=1):
    """Pixel centres (us, vs) of a level image inside RHO_MAX * r, every `stride`-th row and
    column (counted from the image's corner), and their values [N, 3]."""
    h, w = img.shape[:2]
    rm = RHO_MAX * r
    j0, j1 = max(0, int(math.floor(cy - rm))), min(h, int(math.ceil(cy + rm)) + 1)
    i0, i1 = max(0, int(math.floor(cx - rm))), min(w, int(math.ceil(cx + rm)) + 1)
    j0 = (j0 + stride - 1) // stride * stride
    i0 = (i0 + stride - 1) // stride * stride
    jj, ii = np.mgrid[j0:j1:stride, i0:i1:stride]
    us = ii.ravel() + 0.5
    vs = jj.ravel() + 0.5
    keep = (us - cx) ** 2 + (vs - cy) ** 2 <= rm * rm
    us, vs = us[keep], vs[keep]
    return us, vs, img[(vs - 0.5).astype(np.int64), (us - 0.5).astype(np.int64)]


# ---- photometric fit --------------------------------------------------------------------------

def photometric_basis(t, n):
    """The photometric model's columns for one channel: [t, t n_x, t n_y, t n_z, 1]."""
    return np.stack([t, t * n[:, 0], t * n[:, 1], t * n[:, 2], np.ones(len(t))], axis=1)


def photometric_fit(obs, val, n):
    """Per channel least squares of obs ~ val * (a0 + a.n) + b. Returns (model [N, 3],
    shade [N, 3] = the multiplier of val, sse, sst)."""
    model = np.empty_like(obs)
    shade = np.empty_like(obs)
    sse = sst = 0.0
    for c in range(3):
        A = photometric_basis(val[:, c], n)
        AtA = A.T @ A
        Atb = A.T @ obs[:, c]
        coef = _solve_spd(AtA, Atb)
        model[:, c] = A @ coef
        shade[:, c] = coef[0] + coef[1] * n[:, 0] + coef[2] * n[:, 1] + coef[3] * n[:, 2]
        e = obs[:, c] - model[:, c]
        sse += float(e @ e)
        m = obs[:, c].mean()
        sst += float(((obs[:, c] - m) ** 2).sum())
    return model, shade, sse, sst


def colour_share(X):
    """The share of the variance of colours X [N, 3] off their main axis: 1 - the largest
    eigenvalue of their covariance over its trace (0 for a gray image, whatever the gains)."""
    X = np.asarray(X, np.float64)
    d = X - X.mean(axis=0)
    C = d.T @ d
    tr = float(np.trace(C))
    return 1.0 - float(np.linalg.eigvalsh(C)[-1]) / tr if tr > 0 else 0.0


def colour_ratio(obs, model):
    """The frame's colour share over the fitted rendering's (None when the rendering has none)."""
    m = colour_share(model)
    return colour_share(obs) / m if m > 0 else None


def _solve_spd(A, b):
    """A x = b for a symmetric positive semi-definite A (a tiny ridge keeps it solvable)."""
    k = A.shape[0]
    A = A + np.eye(k) * (1e-9 * max(1.0, float(np.trace(A)) / k))
    return np.linalg.solve(A, b)


# ---- refinement -------------------------------------------------------------------------------

class Result:
    """Refined pose and circle, and the alignment residual."""

    def __init__(self, R, circle, residual, iterations, colour=None):
        self.R = R
        self.euler = matrix_to_euler(R)
        self.circle = circle
        self.residual = residual       # after refinement (at the given pose when no steps)
        self.iterations = iterations
        self.colour = colour           # colour ratio (colour_ratio); None for a gray frame

    def __repr__(self):
        return (f"Result(euler={tuple(round(a, 4) for a in self.euler)}, circle={self.circle}, "
                f"residual={self.residual:.4f})")


def _eval(tex, img, us, vs, obs, R, cx, cy, r, fixed_f, want_jac, gray=False, want_model=False):
    if want_jac:
        n, dn = normals_and_derivs(us, vs, cx, cy, r, fixed_f)
    else:
        n, dn = normals(us, vs, cx, cy, r, focal_px(r, fixed_f)), None
    b = n @ R                       # R^T n, row by row
    val, grad = sample(tex, b)
    if gray:
        w = np.asarray(LUMA)
        val = np.repeat((val[:, 0] * w[0] + val[:, 1] * w[1] + val[:, 2] * w[2])[:, None], 3, axis=1)
        g = grad[:, 0, :] * w[0] + grad[:, 1, :] * w[1] + grad[:, 2, :] * w[2]
        grad = np.repeat(g[:, None, :], 3, axis=1)
    model, shade, sse, sst = photometric_fit(obs, val, n)
    if want_model:
        return model
    if not want_jac:
        return sse, sst, None, None
    gw = grad @ R.T                 # world-frame gradients [N, 3, 3]: R g_b
    # d val_c / d omega = g_w x n ; d val_c / d theta_k = g_w . dn_k
    jw = np.cross(gw, n[:, None, :])                           # [N, 3 ch, 3]
    jt = np.einsum("nck,pnk->ncp", gw, dn)                     # [N, 3 ch, 3]
    J = np.concatenate([jw, jt], axis=2) * shade[:, :, None]   # [N, 3, 6]
    e = obs - model
    # Normal equations of the variable-projection problem: the photometric coefficients are
    # refitted at every pose, so a step is judged by what they cannot absorb; J's part that lies
    # in the span of the photometric basis A is projected out (H = J^T J - J^T A (A^T A)^-1 A^T J;
    # g = J^T e, e being orthogonal to A already). Without it, poses and circles that the shading
    # can partly mimic converge slowly.
    H = np.zeros((6, 6))
    g = np.zeros(6)
    for c in range(3):
        Jc = J[:, c, :]
        A = photometric_basis(val[:, c], n)
        AtA = A.T @ A
        JtA = Jc.T @ A
        H += Jc.T @ Jc - JtA @ np.column_stack([_solve_spd(AtA, JtA[i]) for i in range(6)])
        g += Jc.T @ e[:, c]
    return sse, sst, H, g


def residual_at(frame, circle, R, texture_pyr, camera_focal_px=None):
    """The residual at a pose and circle (finest level, no refinement)."""
    return refine(frame, circle, R, texture_pyr, camera_focal_px, iters=(0,) * LEVELS).residual


def refine(frame, circle, R0, texture_pyr, camera_focal_px=None, iters=ITERS, strides=STRIDES):
    """Refine the pose R0 (body to world) and the circle (cx, cy, r) (continuous coordinates
    of the undistorted frame, BGR uint8) against the texture pyramid. Returns a Result."""
    cx, cy, r = (float(v) for v in circle)
    R = np.array(R0, np.float64)
    fpyr, (x0, y0), gray = frame_pyramid(frame, cx, cy, r)
    # work in the crop's coordinates at the finest level
    cx, cy = cx - x0, cy - y0
    total = 0
    final = fine = None
    for lev in range(LEVELS - 1, -1, -1):
        s = 1.0 / (1 << lev)
        img, tex = fpyr[lev], texture_pyr[lev]
        ff = camera_focal_px * s if camera_focal_px else None
        us, vs, obs = pixel_set(img, cx * s, cy * s, r * s, strides[LEVELS - 1 - lev])
        if len(us) < 50:
            continue
        if lev == 0:
            fine = (us, vs, obs)
        steps = iters[LEVELS - 1 - lev]
        if not steps:
            continue
        # Levenberg-Marquardt: a step is kept only when it lowers this level's sum of squares;
        # otherwise the damping grows and the step is taken again from the same point.
        def at(R_, cx_, cy_, r_):
            return _eval(tex, img, us, vs, obs, R_, cx_ * s, cy_ * s, r_ * s, ff, True, gray)
        sse, sst, H, g = at(R, cx, cy, r)
        lam = DAMPING
        for it in range(steps):
            Hd = H.copy()
            Hd[np.diag_indices(6)] *= 1.0 + lam
            d = _solve_spd(Hd, g)
            ang = math.sqrt(float(d[:3] @ d[:3]))
            lim = math.radians(MAX_STEP_DEG)
            if ang > lim:
                d = d * (lim / ang)
            cand = (rotvec_to_matrix(d[:3]) @ R, cx + d[3] / s, cy + d[4] / s, r + d[5] / s)
            if lev > 0 and it + 1 == steps:
                # a coarse level's last step is taken unchecked: the next level starts there and
                # checks its own steps (the same accuracy for one evaluation less per level)
                R, cx, cy, r = cand
                total += 1
                break
            sse_c, sst_c, H_c, g_c = at(*cand)
            if sse_c <= sse:
                R, cx, cy, r = cand
                sse, sst, H, g = sse_c, sst_c, H_c, g_c
                lam = max(DAMPING, lam * 0.1)
                total += 1
            else:
                lam *= 10.0
        if lev == 0:
            final = (sse, sst)
    # the residual: the finest level's pixels (chosen where that level began), at the final pose
    if final is None:
        fine = pixel_set(fpyr[0], cx, cy, r, strides[-1])
        if len(fine[0]) < 50:
            raise ValueError("refine: circle too small or outside the frame")
        final = _eval(texture_pyr[0], fpyr[0], *fine, R, cx, cy, r, camera_focal_px, False, gray)[:2]
    sse, sst = final
    res = sse / sst if sst > 0 else 1.0
    # the colour ratio on the same pixels at the final pose (a gray frame has no colours to compare)
    colour = None
    if not gray:
        model = _eval(texture_pyr[0], fpyr[0], *fine, R, cx, cy, r, camera_focal_px, False, gray, True)
        colour = colour_ratio(fine[2], model)
    return Result(R, (cx + x0, cy + y0, r), res, total, colour)


# ---- confidence -------------------------------------------------------------------------------

def confidence_params(meta_value=None):
    """Thresholds from the metadata value (JSON), over the defaults."""
    p = dict(DEFAULT_CONFIDENCE)
    if meta_value:
        p.update(json.loads(meta_value) if isinstance(meta_value, str) else meta_value)
    return p


def rotation_deg(Ra, Rb):
    """The angle of the rotation from Rb to Ra, degrees."""
    Ra, Rb = np.asarray(Ra, np.float64), np.asarray(Rb, np.float64)
    # |Ra - Rb| (Frobenius) = 2 sqrt(2) sin(t / 2): exact near 0, where acos of the trace is not
    return math.degrees(2.0 * math.asin(min(1.0, float(np.linalg.norm(Ra - Rb)) / (2.0 * math.sqrt(2.0)))))


def refine_checked(frame, circle, R0, texture_pyr, camera_focal_px=None, converge_max_deg=None,
                   passes=CHECK_PASSES, force=False):
    """refine, and the convergence check: (Result, moved, passes run). A gray frame, or an answer
    whose first pass moved the circle more than CHECK_PX pixels or the pose more than CHECK_DEG
    from R0, is refined again from itself until a pass moves the pose at most converge_max_deg
    (at most `passes` passes in all); moved is that last pass's rotation (degrees), None when
    the answer was not checked (force: every answer is). The Result is the last pass's."""
    stop = DEFAULT_CONFIDENCE["converge_max_deg"] if converge_max_deg is None else converge_max_deg
    res = refine(frame, circle, R0, texture_pyr, camera_focal_px)
    shift = max(math.hypot(res.circle[0] - circle[0], res.circle[1] - circle[1]),
                abs(res.circle[2] - circle[2]))
    if not force and res.colour is not None and shift <= CHECK_PX and rotation_deg(res.R, R0) <= CHECK_DEG:
        return res, None, 1
    moved, n = None, 1
    while n < passes:
        try:
            nxt = refine(frame, res.circle, res.R, texture_pyr, camera_focal_px)
        except ValueError:      # the circle ran off (another texture): not converged
            return res, math.inf, n
        if not all(math.isfinite(v) for v in nxt.circle):
            return res, math.inf, n
        moved, res, n = rotation_deg(nxt.R, res.R), nxt, n + 1
        if moved <= stop:
            break
    return res, moved, n


def judge(residual, euler, ranges, params, colour=None, moved=None, refined=True):
    """(confident, note): the residual against its threshold (residual_max_unrefined for the
    network's pose; a refined gray frame's, colour None, residual_max_gray when the model has
    one), the convergence check's last pass against converge_max_deg (checked answers only), the
    colour ratio against its least (colour frames only), then the pose against the model's
    ranges (widened by range_margin_deg)."""
    rmax = params["residual_max"]
    if not refined:
        rmax = params.get("residual_max_unrefined", rmax)
    elif colour is None and params.get("residual_max_gray", 0) > 0:
        rmax = params["residual_max_gray"]
    if not residual <= rmax:
        return False, (f"poor alignment (residual {residual:.3f} > {rmax:.3f}): "
                       f"another texture, a pose outside the model's ranges, or a wrong sphere")
    cmax = params.get("converge_max_deg", DEFAULT_CONFIDENCE["converge_max_deg"])
    if moved is not None and not moved <= cmax:
        return False, (f"not converged (a further pass moved it {moved:.2f} deg > {cmax:.2f}): the "
                       f"start was too far off (a mono camera, a circle found off the sphere)")
    cmin = params.get("colour_min", 0.0)
    if colour is not None and cmin > 0 and not colour >= cmin:
        return False, (f"colours do not match (colour ratio {colour:.2f} < {cmin:.2f}): "
                       f"another texture, or the model's texture without its colours")
    m = params["range_margin_deg"]
    for a, name in zip(euler, "xyz"):
        lo, hi = ranges[name]
        if not lo - m <= a <= hi + m:
            return False, f"outside the model's ranges ({name} = {a:.1f} not in [{lo:g}, {hi:g}])"
    return True, None


# ---- the model's side: texture, thresholds, one frame end to end ------------------------------

class Refiner:
    """What a model file gives refinement: its texture pyramid, thresholds and ranges."""

    def __init__(self, meta, camera=None):
        self.meta = meta
        self.pp = None  # the preprocessing's parameters, read when printed_circle first needs them
        self.texture = texture_pyramid(texture_from_b64(meta[META_TEXTURE])) if META_TEXTURE in meta else None
        self.conf = confidence_params(meta.get(META_CONFIDENCE))
        self.ranges = json.loads(meta.get("spherepose.ranges") or '{"x": [-30, 30], "y": [-30, 30], "z": [-30, 30]}')
        self.focal = None
        if camera is not None:
            from training.preprocess import camera_geometry
            self.focal = camera_geometry(camera)[1]

    def __call__(self, frame, circle, euler, refine_pose=True, cov=None):
        """dict of the result line's members for a frame (undistorted BGR), the circle found
        (continuous coordinates, the radius + 0.5 as network_estimate gives it), the network's
        angles and the found centre's covariance (network_estimate's; None: none); "circle" as
        poseinfer prints it (printed_circle)."""
        R0 = euler_to_matrix(euler)
        if self.texture is None:
            return {"x": euler[0], "y": euler[1], "z": euler[2], "circle": self.printed_circle(frame, circle)}
        moved = None
        if refine_pose:
            res, moved, _ = refine_checked(frame, circle, R0, self.texture, self.focal,
                                           self.conf.get("converge_max_deg"))
        else:
            res = refine(frame, circle, R0, self.texture, self.focal, iters=(0,) * LEVELS)
        ok, note = judge(res.residual, res.euler, self.ranges, self.conf, res.colour, moved, refine_pose)
        out = {"x": res.euler[0], "y": res.euler[1], "z": res.euler[2], "confident": ok,
               "residual": res.residual, "colour": res.colour, "moved": moved}
        if note:
            out["note"] = note
        out["circle"] = self.printed_circle(frame, circle, res.circle if refine_pose and ok else None, cov)
        return out

    def printed_circle(self, frame, circle, refined=None, cov=None):
        """The sphere's circle as poseinfer prints it, continuous coordinates: the localisation's
        (circle as __call__ takes it), or, when a confident answer's refined circle (`refined`)
        has a radius more than RIM_CHECK_PCT percent off it, the rim found from the refined
        circle (sphere-crop-v2 models; the localisation's when rim_from finds none). A confident
        answer's centre is then weighed against the refined centre (fused_centre) by that circle's
        covariance: the localisation's (cov, network_estimate's) or the rim's."""
        from training import preprocess as pp
        found = [circle[0], circle[1], circle[2] - 0.5]
        if refined is None:
            return found
        if self.pp is None:
            self.pp = pp.params(self.meta.get("spherepose.preprocess"))
        p = self.pp
        if p["name"] != pp.NAME_V2:
            return found
        c = (found[0] - 0.5, found[1] - 0.5, found[2])  # OpenCV's pixel centres
        if 100.0 * abs(refined[2] / found[2] - 1.0) > RIM_CHECK_PCT:
            rim_cov = []
            rim = pp.rim_from(frame, (refined[0] - 0.5, refined[1] - 0.5, refined[2]), p, rim_cov)
            if rim is not None:
                c, cov = rim, rim_cov
        f = (refined[0] - 0.5, refined[1] - 0.5)
        if cov is None or len(cov) != 3 or not all(math.isfinite(v) for v in (*cov, *f)):
            return [c[0] + 0.5, c[1] + 0.5, c[2]]
        x, y = fused_centre(c, cov, f)
        return [x + 0.5, y + 0.5, c[2]]


def fused_centre(c, cov, f):
    """The centre c = (x, y) weighed against the refined centre f by c's covariance cov = (cxx,
    cxy, cyy) (preprocess.find_sphere's or rim_from's cov) and CENTRE_FUSE_PX (the refined
    centre's): c + C (C + CENTRE_FUSE_PX^2 I)^-1 (f - c)."""
    t2 = CENTRE_FUSE_PX * CENTRE_FUSE_PX
    cxx, cxy, cyy = cov
    a, b, d = cxx + t2, cxy, cyy + t2
    det = a * d - b * b
    gx, gy = f[0] - c[0], f[1] - c[1]
    ux, uy = (d * gx - b * gy) / det, (a * gy - b * gx) / det
    return c[0] + cxx * ux + cxy * uy, c[1] + cxy * ux + cyy * uy


def network_estimate(sess, meta, frame, camera=None, model="the model"):
    """(undistorted frame, circle in continuous coordinates, network angles, the circle's centre's
    covariance from its rims or None) for a BGR frame; `model` names the model in the error for
    incomplete preprocessing metadata."""
    from training import preprocess as pp
    from training.export import run_onnx
    p = pp.params(meta.get("spherepose.preprocess"), model=str(model))
    if camera is not None and p["name"] != pp.NAME_V1:
        frame = pp.undistort(frame, camera)
    cov = []
    cx, cy, r, bg = pp.find_sphere(frame, p, camera, cov=cov)
    x = pp.normalise(pp.crop(frame, cx, cy, r, bg, p), p)
    e = run_onnx(sess, x[None])["euler_deg"][0].astype(np.float64)
    return frame, (cx + 0.5, cy + 0.5, r + 0.5), tuple(float(v) for v in e), (tuple(cov) or None)


def _frames(paths):
    from pathlib import Path
    exts = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"}
    for p in paths:
        p = Path(p)
        if p.is_dir():
            yield from sorted(q for q in p.iterdir() if q.suffix.lower() in exts)
        else:
            yield p


def settle_deg(frame, circle, R0, texture_pyr, camera_focal_px=None, first=None):
    """What calibration measures of the convergence check on one frame: (the least rotation a
    pass makes, over passes 2 to CHECK_PASSES + 1, and the last pass's residual). A converged
    answer is a fixed point of a pass or swings between two poses (a coarse level's minimum a
    little off the finest one's): that swing is what a right answer's check may show. first:
    the first pass's Result, when already refined."""
    res = first or refine(frame, circle, R0, texture_pyr, camera_focal_px)
    least = math.inf
    for _ in range(CHECK_PASSES):
        try:
            nxt = refine(frame, res.circle, res.R, texture_pyr, camera_focal_px)
        except ValueError:
            return math.inf, 1.0
        if not all(math.isfinite(v) for v in nxt.circle):
            return math.inf, 1.0
        least, res = min(least, rotation_deg(nxt.R, res.R)), nxt
    return least, res.residual


def calibrate(residuals_refined, residuals_unrefined, factor=3.0, floor=0.02, colours=(), settles=(),
              settle_floor=0.1, gray_factor=1.0):
    """Thresholds from in-range held-out frames: `factor` times their 99th percentile
    (at least `floor`); the colour ratio's least: their 1st percentile over `factor` (colour
    frames only; none: no colour check; the residual thresholds too when there are colour
    frames); converge_max_deg: `factor` times the 99th percentile of
    settle_deg's rotations (at least `settle_floor`), of the frames whose residual then passes
    residual_max (settles: (rotation, residual) pairs, None for a frame not measured; none: the
    default); residual_max_gray: `gray_factor` times the 99th percentile of the settled residual
    of the gray frames (colour None) that settled within converge_max_deg with a residual within
    residual_max (none: residual_max holds for gray frames too)."""
    q = lambda a, p=0.99: float(np.quantile(np.asarray(a, np.float64), p))
    colours = list(colours)
    coloured = [c for c in colours if c is not None]
    if coloured and len(coloured) < len(colours):
        # the residual thresholds from the colour frames: a gray frame's first pass may stop
        # degrees short (the convergence check and residual_max_gray are its thresholds)
        keep = [c is not None for c in colours]
        residuals_refined = [a for a, k in zip(residuals_refined, keep) if k]
        residuals_unrefined = [a for a, k in zip(residuals_unrefined, keep) if k]
    out = {"residual_max": round(max(floor, factor * q(residuals_refined)), 4),
           "residual_max_unrefined": round(max(floor, factor * q(residuals_unrefined)), 4),
           "range_margin_deg": DEFAULT_CONFIDENCE["range_margin_deg"],
           "calibrated_on": len(residuals_refined)}
    if coloured:
        out["colour_min"] = round(q(coloured, 0.01) / factor, 4)
    settles = list(settles)
    moves = [d[0] for d in settles if d is not None and d[1] <= out["residual_max"]]
    if moves:
        out["converge_max_deg"] = round(max(settle_floor, factor * q(moves)), 3)
        cmax = out["converge_max_deg"]
        gray = [d[1] for d, c in zip(settles, colours)
                if d is not None and c is None and d[0] <= cmax and d[1] <= out["residual_max"]]
        if gray:
            out["residual_max_gray"] = round(max(floor, gray_factor * q(gray)), 4)
            out["calibrated_on_gray"] = len(gray)
    return out


def main(argv=None):
    import argparse
    import sys
    ap = argparse.ArgumentParser(prog="python -m training.refine", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True, metavar="{add-texture,run,calibrate}")
    a = sub.add_parser("add-texture", help="store a texture PNG in an existing model file "
                       f"(metadata {META_TEXTURE})")
    a.add_argument("--model", required=True, help="ONNX model, rewritten in place")
    a.add_argument("--texture", required=True, help="the texture the model was trained on (PNG, "
                   "width = 2 x height, e.g. build/textures/Texture_3_color.png)")
    r = sub.add_parser("run", help="network + refinement on frames: one JSON line each, as poseinfer")
    r.add_argument("--model", required=True)
    r.add_argument("--camera-file", default=None, help="camera JSON (focal length, distortion); frames "
                   "whose folder has a truth.jsonl of rig scenes use the camera it gives them")
    r.add_argument("--no-refine", action="store_true", help="the network's angles, residual at them")
    r.add_argument("frames", nargs="+", help="image files or folders")
    c = sub.add_parser("calibrate", help="confidence thresholds from held-out in-range frames "
                       f"(metadata {META_CONFIDENCE})")
    c.add_argument("--model", required=True)
    c.add_argument("--camera-file", default=None, help="as for run")
    c.add_argument("--factor", type=float, default=3.0, help="residual threshold = factor x 99th percentile; "
                   "least colour ratio = 1st percentile / factor; converge_max_deg = factor x 99th "
                   "percentile of a converged answer's swing")
    c.add_argument("--gray-factor", type=float, default=1.0, help="residual_max_gray = gray-factor x 99th "
                   "percentile of the gray frames' settled residual (a mono camera sees the texture and its "
                   "colourless version a few hundredths apart)")
    c.add_argument("--keys", default=None, help="comma-separated: write only these thresholds, over the "
                   "model's others (e.g. converge_max_deg,residual_max_gray)")
    c.add_argument("--write", action="store_true", help="store the thresholds in the model file")
    c.add_argument("frames", nargs="+", help="in-range frames the model was not trained on")
    args = ap.parse_args(argv)
    from training.export import onnx_session, read_metadata, set_metadata
    try:
        if args.cmd == "add-texture":
            set_metadata(args.model, {META_TEXTURE: texture_png_b64(args.texture)})
            print(f"{args.model}: texture {args.texture} stored ({META_TEXTURE})")
            return 0
        import cv2
        meta = read_metadata(args.model)
        if META_TEXTURE not in meta:
            raise ValueError(f"{args.model}: no texture (metadata {META_TEXTURE}); add it with add-texture")
        camera = None
        if args.camera_file:
            from sim.camera import load_camera
            camera = load_camera(args.camera_file)
        from training.data import frame_camera
        from training.preprocess import NoSphere, camera_geometry
        sess = onnx_session(args.model, 1)
        ref, folder_cams = Refiner(meta, None), {}
        rows = []
        for path in _frames(args.frames):
            frame = cv2.imread(str(path), cv2.IMREAD_COLOR)
            if frame is None:
                print(json.dumps({"file": str(path), "error": "cannot decode image"}), flush=True)
                continue
            # a rig scene's frame carries its own camera in its folder's truth.jsonl
            cam = frame_camera(folder_cams, path, frame, camera)
            ref.focal = None if cam is None else camera_geometry(cam)[1]
            try:
                frame, circle, euler, cov = network_estimate(sess, meta, frame, cam, args.model)
            except NoSphere as e:
                print(json.dumps({"file": str(path), "error": str(e)}), flush=True)
                continue
            if args.cmd == "run":
                out = {"file": str(path), **ref(frame, circle, euler, not args.no_refine, cov)}
                print(json.dumps(out), flush=True)
            else:
                # the first pass's residual and colour ratio (unchecked), and the check's swing
                one = refine(frame, circle, euler_to_matrix(euler), ref.texture, ref.focal)
                rows.append((one.residual, ref(frame, circle, euler, False)["residual"], one.colour,
                             settle_deg(frame, circle, None, ref.texture, ref.focal, one)))
        if args.cmd == "calibrate":
            if len(rows) < 20:
                raise ValueError(f"calibrate: {len(rows)} frames; give at least 20")
            conf = calibrate([a for a, _, _, _ in rows], [b for _, b, _, _ in rows], args.factor,
                             colours=[c for _, _, c, _ in rows], settles=[d for _, _, _, d in rows],
                             gray_factor=args.gray_factor)
            if args.keys:
                keys = [k.strip() for k in args.keys.split(",") if k.strip()]
                missing = [k for k in keys if k not in conf]
                if missing:
                    raise ValueError(f"calibrate: no {', '.join(missing)} from these frames")
                old = json.loads(meta.get(META_CONFIDENCE) or "{}")
                conf = dict(old, **{k: conf[k] for k in keys})
            print(json.dumps(conf, sort_keys=True))
            if args.write:
                set_metadata(args.model, {META_CONFIDENCE: json.dumps(conf, sort_keys=True)})
        return 0
    except (OSError, ValueError) as e:
        print(f"python -m training.refine: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
