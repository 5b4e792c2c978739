"""A colour camera's image pipeline after the optics, for the `rig-sensor` family.

render.camera_effects treats the frame as if every pixel saw red, green and
blue. A real colour camera does not, and what its pipeline does to an edge
can move the place where a channel steps most. Here, in the order a camera
applies them:

1. Lateral chromatic aberration (the lens; after exposure, vignetting and
   blur). The red and blue images are scaled about the lens's principal
   point (cam.principal, the point the lens distortion is centred on) by
   factors 1 + d_r and 1 + d_b, |d| in [0.0005, 0.003] with either sign:
   up to about 1.2 px at the corners of 640x512. Green is the reference and
   is not moved, so the truth circle (render.circle) stays the outline of
   the sphere in the green image. Resampling is bilinear.
2. The colour filter array (the sensor). Each pixel keeps one channel, in
   one of the four Bayer layouts RGGB, BGGR, GRBG, GBRG. The pixel clips at
   full scale (1.0).
3. Read and shot noise, on the raw values (scene["noise"], as the other
   families).
4. White-balance gains, one per channel in [0.8, 1.25], on the raw values.
   The result clips at full scale again, and is quantised to 8 bits (a
   BayerRG8-style raw).
5. Demosaicing with OpenCV: bilinear, VNG or edge-aware (EA).
6. Gamma (scene["gamma"]).
7. Sharpening: an unsharp mask img + a (img - G_s * img), with amount a in
   [0, 1] and a Gaussian of sigma s in [0.5, 1.5] px, on 60 % of frames.
8. 8 bits, then JPEG (scene["jpeg"]).

`pipeline(..., off=...)` leaves stages out, for measuring what each one costs
(the family's draws do not change). Its names: "ca", "cfa" (no mosaic and no
demosaic: every pixel keeps all three channels), "wb", "sharpen".
"""
import cv2
import numpy as np

CFA_LAYOUTS = ("RGGB", "BGGR", "GRBG", "GBRG")
DEMOSAIC = {"bilinear": "", "vng": "_VNG", "ea": "_EA"}
STAGES = ("ca", "cfa", "wb", "sharpen")
CA_RANGE = (0.0005, 0.003)
WB_RANGE = (0.8, 1.25)
SHARPEN_SHARE = 0.6
SHARPEN_AMOUNT = (0.0, 1.0)
SHARPEN_RADIUS = (0.5, 1.5)
_CHANNEL = {"R": 0, "G": 1, "B": 2}


def draw(rng):
    """The pipeline's parameters for one frame (JSON-ready)."""
    ca = [float(rng.choice([-1.0, 1.0]) * rng.uniform(*CA_RANGE)) for _ in range(2)]
    sharpen = None
    if rng.random() < SHARPEN_SHARE:
        sharpen = {"amount": float(rng.uniform(*SHARPEN_AMOUNT)), "radius_px": float(rng.uniform(*SHARPEN_RADIUS))}
    return {"ca": {"red": 1.0 + ca[0], "blue": 1.0 + ca[1]},
            "cfa": str(rng.choice(CFA_LAYOUTS)),
            "demosaic": str(rng.choice(list(DEMOSAIC))),
            "wb": [float(g) for g in rng.uniform(*WB_RANGE, 3)],
            "sharpen": sharpen}


def lateral_ca(img, scale_red, scale_blue, centre):
    """RGB float image with red and blue magnified by their factors about `centre` (continuous
    pixels: pixel (c, r) covers [c, c+1)); green unchanged."""
    out = img.copy()
    h, w = img.shape[:2]
    cu, cv = centre
    for ch, k in ((0, scale_red), (2, scale_blue)):
        # output pixel centre (x + 0.5) shows the scene point at cu + (x + 0.5 - cu) / k
        m = np.float32([[1 / k, 0, cu + (0.5 - cu) / k - 0.5], [0, 1 / k, cv + (0.5 - cv) / k - 0.5]])
        out[..., ch] = cv2.warpAffine(np.ascontiguousarray(img[..., ch]), m, (w, h),
                                      flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                      borderMode=cv2.BORDER_REPLICATE)
    return out


def channel_map(layout, h, w):
    """[h, w] index of the channel (0 R, 1 G, 2 B) each pixel of a Bayer `layout` keeps."""
    cell = np.array([[_CHANNEL[layout[0]], _CHANNEL[layout[1]]], [_CHANNEL[layout[2]], _CHANNEL[layout[3]]]])
    return np.tile(cell, ((h + 1) // 2, (w + 1) // 2))[:h, :w]


def mosaic(img, layout):
    """One channel per pixel, as the colour filter array `layout` samples the RGB image."""
    idx = channel_map(layout, *img.shape[:2])
    return np.take_along_axis(img, idx[..., None], axis=2)[..., 0]


def demosaic(raw8, layout, method):
    """RGB uint8 from an 8-bit Bayer raw, by OpenCV's `method` (bilinear, vng or ea)."""
    code = getattr(cv2, f"COLOR_Bayer{layout}2BGR{DEMOSAIC[method]}")
    return cv2.cvtColor(raw8, code)[..., ::-1].copy()


def unsharp(img, amount, radius_px):
    """img + amount * (img - Gaussian(img, sigma radius_px)): overshoot on both sides of an edge."""
    soft = cv2.GaussianBlur(img, (0, 0), radius_px, borderType=cv2.BORDER_REFLECT)
    return img + np.float32(amount) * (img - soft)


def pipeline(img, scene, cam, off=()):
    """RGB uint8 [H, W, 3] from the optics' RGB float image (exposure, vignetting and blur applied),
    through scene["sensor"]'s stages; the stages named in `off` are left out."""
    unknown = set(off) - set(STAGES)
    if unknown:
        raise ValueError(f"unknown sensor stage(s) {sorted(unknown)} (valid: {', '.join(STAGES)})")
    sen = scene["sensor"]
    rng = np.random.default_rng(scene["seed"])
    img = img.astype(np.float32)
    if "ca" not in off:
        img = lateral_ca(img, sen["ca"]["red"], sen["ca"]["blue"], cam.principal)
    img = np.clip(img, 0.0, 1.0)                              # the pixel's full scale
    mosaic_on = "cfa" not in off
    raw = mosaic(img, sen["cfa"]) if mosaic_on else img
    noise = scene.get("noise")
    if noise:
        sigma = np.sqrt((noise["read"] / 255.0) ** 2 + noise["shot"] / 255.0 * raw)
        raw = raw + sigma * rng.standard_normal(raw.shape).astype(np.float32)
    if "wb" not in off:
        gains = np.float32(sen["wb"])
        raw = raw * (gains[channel_map(sen["cfa"], *raw.shape)] if mosaic_on else gains)
    raw8 = np.clip(np.floor(np.clip(raw, 0.0, 1.0) * 255.0 + 0.5), 0, 255).astype(np.uint8)
    rgb = demosaic(raw8, sen["cfa"], sen["demosaic"]) if mosaic_on else raw8
    img = (rgb.astype(np.float32) / 255.0) ** np.float32(1.0 / scene["gamma"])
    if sen.get("sharpen") and "sharpen" not in off:
        img = unsharp(img, sen["sharpen"]["amount"], sen["sharpen"]["radius_px"])
    return output_8bit(img, scene.get("jpeg", 0))


def output_8bit(img, q):
    """Every camera's last stage (render.camera_effects' too): float RGB in 0..1 to 8 bits
    (rounded), then a JPEG round trip at quality q (0: none)."""
    out = np.clip(np.floor(img * 255.0 + 0.5), 0, 255).astype(np.uint8)
    if q:
        ok, buf = cv2.imencode(".jpg", cv2.cvtColor(out, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, int(q)])
        out = cv2.cvtColor(cv2.imdecode(buf, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    return out
