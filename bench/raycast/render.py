"""One frame of a scene: exact rays, texture lookup, shading, then the camera's own effects.

Per pixel, a ray from the camera centre (0, 0, D) meets the sphere (radius R
at the origin) or a mount part or nothing (the backdrop). Where it meets the
sphere at world point P, the outward normal is n = P / R, its body direction
b = R_pose^T n, and the texture is read at latitude asin(b_y) and longitude
atan2(b_x, b_z) (docs/conventions.md "Texture mapping"), bilinearly.

Anti-aliasing: one ray per pixel finds what each pixel sees; the pixels on
the sphere and those next to an outline get `supersample` x `supersample`
rays, averaged (the texture's detail is finer than a pixel on the sphere).

Shading (not the training renderer's model): Lambert for every light plus a
Blinn-Phong sheen, and an ambient term, on the texture's values as albedo.
Then, in this order: exposure, vignetting (light falls off toward the
corners), defocus or Gaussian blur (optics), sensor noise (read noise plus
shot noise), gamma, 8-bit quantisation, JPEG compression and decoding.
The `rig-sensor` family's scenes carry a "sensor" record: after the optics
(exposure, vignetting, blur) their frames go through sensor.py's colour
camera pipeline instead (lateral colour, Bayer mosaic, noise, white balance,
demosaicing, gamma, sharpening, JPEG).
The `rig-motion` family's scenes carry a "motion" record: the sphere's
radiance is the mean of sub-exposures along a sweep of its pose
(exposure_radiance), and a line smear follows the blur in the optics.
"""
import math

import cv2
import numpy as np

from . import backgrounds, camera, mounts, sensor, shapes

SPHERE, BACKDROP = 0, -1      # hit ids; mount parts are 1, 2, ...; other spheres OTHERS + j
OTHERS = 1000
CHUNK_RAYS = 1 << 15          # rays traced at once: about 1 MB per float64 array
MOTION_STEPS = 8              # sub-exposures of a scene with motion (exposure_radiance)


def euler_matrix(x_deg, y_deg, z_deg):
    """R = Rz(z) Ry(y) Rx(x), body to world (docs/conventions.md)."""
    a, b, c = np.radians([x_deg, y_deg, z_deg])
    rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    rz = np.array([[math.cos(c), -math.sin(c), 0], [math.sin(c), math.cos(c), 0], [0, 0, 1]])
    return rz @ ry @ rx


def load_texture(path):
    """Equirectangular texture as float32 RGB in 0..1; the file must be 2:1."""
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise ValueError(f"{path}: cannot read the texture image")
    if img.shape[1] != 2 * img.shape[0]:
        raise ValueError(f"{path}: texture is {img.shape[1]} x {img.shape[0]}, width must be twice the height")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB).astype(np.float32) / 255.0


def texture_lookup(tex, body):
    """Bilinear texture value at unit body directions [N, 3] (continuous texel coordinates: the
    centre of texel (c, r) is at (c + 0.5, r + 0.5); longitude wraps, rows clamp at the poles)."""
    h, w = tex.shape[:2]
    body = body.astype(np.float32)            # float32: 1e-7 rad is far below a texel
    lat = np.arcsin(np.clip(body[:, 1], -1.0, 1.0))
    lon = np.arctan2(body[:, 0], body[:, 2])
    u = (lon + np.float32(np.pi)) * np.float32(w / (2 * np.pi)) - np.float32(0.5)
    v = (np.float32(np.pi / 2) - lat) * np.float32(h / np.pi) - np.float32(0.5)
    c0 = np.floor(u)
    r0 = np.floor(v)
    fu = (u - c0)[:, None]
    fv = (v - r0)[:, None]
    c0 = c0.astype(np.int64) % w
    c1 = (c0 + 1) % w
    r1 = np.clip(r0 + 1, 0, h - 1).astype(np.int64) * w
    r0 = np.clip(r0, 0, h - 1).astype(np.int64) * w
    flat = tex.reshape(-1, 3)
    top = np.take(flat, r0 + c0, axis=0) * (1 - fu) + np.take(flat, r0 + c1, axis=0) * fu
    bottom = np.take(flat, r1 + c0, axis=0) * (1 - fu) + np.take(flat, r1 + c1, axis=0) * fu
    return top * (1 - fv) + bottom * fv


def frame_camera(scene, cam):
    return cam.at(distance_mm=float(scene["distance_mm"]))


def trace(scene, cam, u, v, with_mount=True):
    """What the rays through frame points (u, v) meet: hit id [N] (SPHERE, mount part k >= 1 or
    BACKDROP), world points [N, 3], normals [N, 3], ray directions [N, 3]. with_mount=False: the
    sphere alone (for rays known to see nothing else)."""
    u, v = np.ravel(u), np.ravel(v)
    if len(u) > CHUNK_RAYS:                     # in chunks that stay in the CPU's caches
        parts = [trace(scene, cam, u[k:k + CHUNK_RAYS], v[k:k + CHUNK_RAYS], with_mount)
                 for k in range(0, len(u), CHUNK_RAYS)]
        return tuple(np.concatenate(a) for a in zip(*parts))
    cam = frame_camera(scene, cam)
    o = np.array([0.0, 0.0, cam.distance_mm])
    d = camera.pixel_rays(cam, u, v, scene.get("shift_px", (0.0, 0.0))).reshape(-1, 3)
    if scene.get("sphere", True):
        t_best, n_best = shapes.sphere_hit(o, d, cam.radius_mm)
    else:                                       # a frame without the sphere (the evaluation's refusals)
        t_best, n_best = np.full(len(d), shapes.INF), np.zeros((len(d), 3))
    hit = np.where(np.isfinite(t_best), SPHERE, BACKDROP)
    parts = mounts.solids(scene.get("mount"), cam.radius_mm) if with_mount else []
    if with_mount:
        for j, other in enumerate(scene.get("others", [])):   # more spheres, same size, own poses
            c = np.asarray(other["centre_mm"], np.float64)
            parts.append((lambda o_, d_, c=c: shapes.sphere_hit(o_ - c, d_, cam.radius_mm), OTHERS + j))
    for k, (fn, mat) in enumerate(parts, start=1):
        k = mat if isinstance(mat, int) else k
        t, n = fn(o, d)
        nearer = t < t_best
        t_best = np.where(nearer, t, t_best)
        n_best = np.where(nearer[:, None], n, n_best)
        hit = np.where(nearer, k, hit)
    p = o[None, :] + np.where(np.isfinite(t_best), t_best, 0.0)[:, None] * d
    return hit, p, n_best, d


def surface_coords(scene, cam, u, v):
    """Texture (lat, lon) in degrees seen at frame points (u, v); NaN where the sphere is not seen."""
    hit, _, n, _ = trace(scene, cam, u, v)
    body = shapes.rows_mat(n, euler_matrix(*scene["pose"]))   # rows: (R^T n)^T = n^T R
    lat = np.degrees(np.arcsin(np.clip(body[:, 1], -1, 1)))
    lon = np.degrees(np.arctan2(body[:, 0], body[:, 2]))
    seen = hit == SPHERE
    return np.where(seen, lat, np.nan), np.where(seen, lon, np.nan)


def hidden_rim_fraction(scene, cam, samples=720):
    """Share of the sphere's outline that a mount hides, by rays just inside the outline."""
    c = circle(scene, cam)
    a = np.linspace(0, 2 * np.pi, samples, endpoint=False)
    rr = c[2] - 0.75
    pin = cam.at(distortion=(0.0,) * 5)            # rays through the pinhole image: no lens
    hit, _, _, _ = trace(scene, pin, c[0] + rr * np.cos(a), c[1] + rr * np.sin(a))
    return float(np.mean(hit != SPHERE))


def circle(scene, cam):
    """The sphere's outline (cx, cy, r) in the undistorted image, continuous pixels."""
    fc = frame_camera(scene, cam)
    u0, v0 = cam.principal
    du, dv = scene.get("shift_px", (0.0, 0.0))
    return (u0 + du, v0 + dv, fc.radius_px())


def _shade(scene, cam, tex, hit, p, n, d):
    """Radiance (float32 RGB, about 0..1) of each ray's hit; NaN for the backdrop (filled later)."""
    out = np.full((len(hit), 3), np.nan, np.float32)
    solids = mounts.solids(scene.get("mount"), cam.radius_mm)
    materials = [{"colour": None, "specular": scene["sheen"]["specular"], "power": scene["sheen"]["power"]}]
    materials += [m for _, m in solids]
    materials = list(enumerate(materials))
    materials += [(OTHERS + j, dict(materials[0][1], pose=other["pose"]))
                  for j, other in enumerate(scene.get("others", []))]
    for k, mat in materials:
        sel = np.nonzero(hit == k)[0]
        if not len(sel):
            continue
        nk = n[sel]
        if k == SPHERE or k >= OTHERS:
            pose = scene["pose"] if k == SPHERE else mat["pose"]
            albedo = texture_lookup(tex, shapes.rows_mat(nk, euler_matrix(*pose)))
        else:
            albedo = np.broadcast_to(np.asarray(mat["colour"], np.float32), (len(nk), 3))
        nk = nk.astype(np.float32)
        view = -d[sel].astype(np.float32)
        light = np.full((len(nk), 3), scene["ambient"], np.float32)
        spec = np.zeros((len(nk), 3), np.float32)
        for li in scene["lights"]:
            ldir = np.asarray(li["direction"], np.float64)
            ldir = (ldir / np.linalg.norm(ldir)).astype(np.float32)
            col = (np.asarray(li["colour"], np.float64) * li["intensity"]).astype(np.float32)
            ndl = np.maximum(shapes.rows_dot(nk, ldir), 0.0)
            light += ndl[:, None] * col
            if mat["specular"] > 0:
                h = view + ldir
                h /= np.sqrt(np.einsum("ij,ij->i", h, h))[:, None]
                ndh = np.maximum(np.einsum("ij,ij->i", nk, h), 1e-30)
                s = np.float32(mat["specular"]) * np.where(ndl > 0, np.exp(np.float32(mat["power"]) * np.log(ndh)), 0)
                spec += s[:, None] * col
        out[sel] = albedo * light + spec
    return out


def radiance(scene, cam, tex, supersample=4):
    """Scene radiance [H, W, 3] float32 before the camera's effects."""
    w, h = cam.width, cam.height
    bg = backgrounds.make(scene["background"], w, h)
    ys, xs = np.mgrid[0:h, 0:w]
    hit, p, n, d = trace(scene, cam, xs + 0.5, ys + 0.5)
    hit = hit.reshape(h, w)
    # Pixels to supersample: on the sphere, or beside a change of what is seen.
    ids = hit.astype(np.int16)
    edge = (cv2.dilate(ids, np.ones((3, 3), np.uint8)) != cv2.erode(ids, np.ones((3, 3), np.uint8)))
    fine = (hit == SPHERE) | (hit >= OTHERS) | edge
    img = bg.copy()
    coarse = ~fine & (hit != BACKDROP)
    if coarse.any():
        sel = coarse.ravel()
        img[coarse] = _shade(scene, cam, None, hit.ravel()[sel], p[sel], n[sel], d[sel])
    # Pixels whose 3x3 neighbourhood sees the sphere alone: their sub-rays need the sphere test only.
    inside = cv2.erode((hit == SPHERE).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    for group, with_mount in ((fine & inside, False), (fine & ~inside, True)):
        gy, gx = np.nonzero(group)
        s = supersample
        off = (np.arange(s) + 0.5) / s
        ou, ov = np.meshgrid(off, off)
        step = max(1, CHUNK_RAYS // (s * s))
        for k in range(0, len(gy), step):       # in chunks that stay in the CPU's caches
            fy, fx = gy[k:k + step], gx[k:k + step]
            u = fx[:, None] + ou.ravel()[None, :]
            v = fy[:, None] + ov.ravel()[None, :]
            sh, sp, sn, sd = trace(scene, cam, u, v, with_mount)
            col = _shade(scene, cam, tex, sh, sp, sn, sd).reshape(len(fy), s * s, 3)
            back = np.repeat(bg[fy, fx][:, None, :], s * s, axis=1)
            col = np.where(np.isnan(col), back, col)
            img[fy, fx] = col.mean(axis=1)
    return img


def exposure_radiance(scene, cam, tex, supersample=4):
    """The radiance the sensor integrates over the exposure: radiance() itself, or for a scene with
    a "motion" record the mean of MOTION_STEPS sub-exposures whose poses lie evenly (at the middles
    of MOTION_STEPS equal steps) across pose +- sweep_deg / 2: symmetric about the frame's pose,
    its truth."""
    motion = scene.get("motion")
    if not motion:
        return radiance(scene, cam, tex, supersample)
    total = None
    for k in range(MOTION_STEPS):
        t = (k + 0.5) / MOTION_STEPS - 0.5
        pose = [p + t * s for p, s in zip(scene["pose"], motion["sweep_deg"])]
        img = radiance(dict(scene, pose=pose), cam, tex, supersample)
        total = img if total is None else total + img
    return total / np.float32(MOTION_STEPS)


def _line_kernel(length, angle_deg):
    """Motion smear: a segment of `length` px at `angle_deg` (image x towards y) seen by each tap
    through a tent of one pixel each way (bilinear): the tap's weight is the sum over 256 points
    evenly along the segment of (1 - |dx|)(1 - |dy|), where both are under 1; normalised."""
    n = int(math.ceil(length / 2)) + 1
    a = math.radians(angle_deg)
    s = ((np.arange(256) + 0.5) / 256 - 0.5) * length
    px, py = s * math.cos(a), s * math.sin(a)                  # the points, about the middle tap
    taps = np.arange(-n, n + 1, dtype=np.float64)
    wx = np.clip(1.0 - np.abs(taps[:, None] - px[None, :]), 0.0, None)   # [tap x, point]
    wy = np.clip(1.0 - np.abs(taps[:, None] - py[None, :]), 0.0, None)   # [tap y, point]
    k = wy @ wx.T                                               # [tap y, tap x]
    return (k / k.sum()).astype(np.float32)


def _disc_kernel(radius):
    """Defocus: a uniform disc of `radius` px, its edge anti-aliased by 8x8 sub-samples."""
    n = int(math.ceil(radius)) + 1
    sub = (np.arange(8) + 0.5) / 8 - 0.5
    ys, xs = np.mgrid[-n:n + 1, -n:n + 1].astype(np.float64)
    k = np.zeros_like(xs)
    for a in sub:
        for b in sub:
            k += (xs + a) ** 2 + (ys + b) ** 2 <= radius * radius
    if k.sum() == 0:            # a disc smaller than the sub-sample spacing: no blur
        k[n, n] = 1.0
    return (k / k.sum()).astype(np.float32)


def optics(img, scene, cam):
    """Exposure, vignetting and blur: what the lens does before the sensor (float RGB)."""
    img = img * np.float32(scene["exposure"])
    vig = scene.get("vignetting", 0.0)
    if vig:
        h, w = img.shape[:2]
        u0, v0 = cam.principal
        ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
        rho2 = ((xs + 0.5 - u0) ** 2 + (ys + 0.5 - v0) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
        img = img * (1.0 - vig * rho2)[..., None]     # vig = light lost at the corners
    blur = scene.get("blur")
    if blur and blur["px"] > 0:
        if blur["kind"] == "disc":
            img = cv2.filter2D(img, -1, _disc_kernel(blur["px"]), borderType=cv2.BORDER_REFLECT)
        else:
            img = cv2.GaussianBlur(img, (0, 0), blur["px"], borderType=cv2.BORDER_REFLECT)
    motion = scene.get("motion")
    if motion and motion["line_px"] > 0:
        img = cv2.filter2D(img, -1, _line_kernel(motion["line_px"], motion["line_deg"]),
                           borderType=cv2.BORDER_REFLECT)
    return img


def camera_effects(img, scene, cam):
    """Exposure, vignetting, blur, noise, gamma, 8 bits and JPEG: RGB uint8 [H, W, 3]."""
    rng = np.random.default_rng(scene["seed"])
    img = optics(img, scene, cam)
    noise = scene.get("noise")
    if noise:
        lin = np.clip(img, 0.0, 1.0)
        sigma = np.sqrt((noise["read"] / 255.0) ** 2 + noise["shot"] / 255.0 * lin)
        img = lin + sigma * rng.standard_normal(img.shape).astype(np.float32)
    img = np.clip(img, 0.0, 1.0) ** np.float32(1.0 / scene["gamma"])
    return sensor.output_8bit(img, scene.get("jpeg", 0))


def render(scene, cam, tex, supersample=4):
    """RGB uint8 frame [H, W, 3] of `scene` seen by `cam` (texture `tex` from load_texture): the
    radiance over the exposure (exposure_radiance: a "motion" record's sweep), then the camera's
    effects; a scene with a "sensor" record goes through a colour camera's pipeline (sensor.py)
    after the optics."""
    img = exposure_radiance(scene, cam, tex, supersample)
    if scene.get("sensor"):
        return sensor.pipeline(optics(img, scene, cam), scene, cam)
    return camera_effects(img, scene, cam)
