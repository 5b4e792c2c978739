"""Exact ray intersections with the scene's solids: the sphere, finite cylinders and boxes.

All rays start at one point `o` (the camera centre) and have unit directions
`d` [N, 3]. Each `hit` returns the distance t [N] along the ray to the first
surface in front of the camera (inf where the ray misses) and the outward
unit normal there [N, 3] (only meaningful where t is finite).
"""
import numpy as np

INF = np.inf


def rows_dot(a, v):
    """a [N, 3] . v [3] per row, without BLAS (whose threads only cost time at these shapes)."""
    return a[:, 0] * v[0] + a[:, 1] * v[1] + a[:, 2] * v[2]


def rows_mat(a, m):
    """a [N, 3] @ m [3, 3], row by row, without BLAS."""
    return a[:, 0:1] * m[0][None, :] + a[:, 1:2] * m[1][None, :] + a[:, 2:3] * m[2][None, :]


def _first_positive(t1, t2):
    """The nearer of two roots that lies in front (t > 0), inf when neither does."""
    t = np.where(t1 > 1e-9, t1, np.where(t2 > 1e-9, t2, INF))
    return t


def sphere_hit(o, d, radius):
    """Sphere of `radius` at the origin: |o + t d|^2 = R^2, nearer root."""
    b = rows_dot(d, o)                          # d . o
    c = float(o @ o) - radius * radius
    disc = b * b - c
    ok = disc >= 0.0
    s = np.sqrt(np.where(ok, disc, 0.0))
    t = np.where(ok, _first_positive(-b - s, -b + s), INF)
    n = (o[None, :] + np.where(np.isfinite(t), t, 0.0)[:, None] * d) / radius
    return t, n


def cylinder_hit(o, d, base, axis, radius, length):
    """Solid cylinder from `base` along unit `axis` for `length` mm, with flat end caps. Only rays that
    meet the infinite cylinder (a cheap test) are followed further: a ray through a cap does too."""
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    ob = o - np.asarray(base, np.float64)
    oa = float(ob @ axis)
    op = ob - oa * axis
    da_all = rows_dot(d, axis)
    b_all = rows_dot(d, op)
    a_all = 1.0 - da_all * da_all               # |d - (d.a) a|^2 for unit d
    c = float(op @ op) - radius * radius
    cand = np.nonzero((b_all * b_all - a_all * c >= 0.0) & (a_all > 1e-15))[0]
    t_out = np.full(len(d), INF)
    n_out = np.zeros((len(d), 3))
    if len(cand) == 0:
        return t_out, n_out
    dc, da, a, b = d[cand], da_all[cand], a_all[cand], b_all[cand]
    s = np.sqrt(np.maximum(b * b - a * c, 0.0))
    t_side = np.full(len(cand), INF)
    for root in ((-b - s) / a, (-b + s) / a):
        h = oa + root * da                      # position along the axis
        good = (root > 1e-9) & (h >= 0.0) & (h <= length) & (root < t_side)
        t_side = np.where(good, root, t_side)
    # End caps: planes h = 0 and h = length, inside the radius.
    t_cap = np.full(len(cand), INF)
    cap_sign = np.zeros(len(cand))
    da_safe = np.where(np.abs(da) > 1e-15, da, 1e-15)
    for h0, sign in ((0.0, -1.0), (length, 1.0)):
        root = (h0 - oa) / da_safe
        q = op[None, :] + root[:, None] * (dc - da[:, None] * axis)
        good = (root > 1e-9) & (np.einsum("ij,ij->i", q, q) <= radius * radius) & (root < t_cap)
        t_cap = np.where(good, root, t_cap)
        cap_sign = np.where(good, sign, cap_sign)
    t = np.minimum(t_side, t_cap)
    p = ob[None, :] + np.where(np.isfinite(t), t, 0.0)[:, None] * dc
    radial = p - rows_dot(p, axis)[:, None] * axis
    n_side = radial / np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), 1e-12)
    t_out[cand] = t
    n_out[cand] = np.where((t_cap < t_side)[:, None], cap_sign[:, None] * axis[None, :], n_side)
    return t_out, n_out


def box_hit(o, d, center, rotation, half):
    """Box with half extents `half` (its own axes) turned by `rotation` (columns: its axes in the world)
    about `center`: the slab method in the box's frame."""
    rot = np.asarray(rotation, np.float64)
    ol = rot.T @ (o - np.asarray(center, np.float64))
    dl = rows_mat(d, rot)                       # directions in the box frame
    half = np.asarray(half, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / np.where(np.abs(dl) > 1e-15, dl, 1e-15)
        t1 = (-half - ol) * inv
        t2 = (half - ol) * inv
    tmin = np.minimum(t1, t2)
    tmax = np.maximum(t1, t2)
    t_near = tmin.max(axis=1)
    t_far = tmax.min(axis=1)
    ok = (t_near <= t_far) & (t_far > 1e-9)
    t = np.where(ok, np.where(t_near > 1e-9, t_near, t_far), INF)
    face = tmin.argmax(axis=1)                  # the slab entered last is the face hit
    sign = -np.sign(dl[np.arange(len(d)), face])
    nl = np.zeros_like(dl)
    nl[np.arange(len(d)), face] = sign
    return t, rows_mat(nl, rot.T)
