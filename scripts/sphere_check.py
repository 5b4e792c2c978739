#!/usr/bin/env python3
"""What the sphere finder sees in your camera's frames: run it on a few frames before a rig run.

usage: sphere_check.py [--model M.onnx] [--camera-file CAM.json] [--out DIR] [--json] IMAGE|DIR ...

For each frame: the circle poseinfer would measure the pose in (the same localisation,
sphere-crop-v2, with the model's parameters; the Python reference gives the C runtime's circle to
the last bit), in poseinfer's `circle` coordinates (pixel (c, r) covers [c, c+1)), and on how many
of its rays the rim was found. When the frame would be refused:
poseinfer's error, the best circle the finder had, and what on the rig to change. The rays whose
rim is not found are told apart:

  crowded   beyond the rim (up to support_flank_px outside it) lies an edge at least as strong
            as the rim's, and one the finder counts (support_edge_min): the mount, clutter or a
            shadow touching the sphere
  faint     else: the rim's step is too weak to stand out of the texture's own edges and the
            noise: the sphere's edge and the backdrop beyond it alike in colour and brightness,
            or the edge blurred (focus, motion)
  outside   the ray leaves the frame

--out DIR writes DIR/<name>_check.png: the frame (undistorted with a camera file) with that
circle and a tick on each ray, green where the rim was found, red faint, orange crowded, grey
outside. --json prints one JSON object per frame instead of the text lines; without it, several
frames end with a line that counts the answered (and the range of their rim shares), refused and
not checked ones.

Exit status: 0 every frame answered; 1 some frame refused, not checked (unreadable, or not of
the camera file's size) or its drawing not written; 2 usage error (model, camera file, no
images, --out not a folder).
"""
import argparse
import json
import math
import os
import sys
from pathlib import Path

import cv2
import numpy as np

from sim.camera import CameraError, load_camera
from training import preprocess as pp
from training.export import read_metadata

REPO = Path(__file__).resolve().parents[1]
MODEL = REPO / "training" / "models" / "Texture_3_color.onnx"
IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"}

# A ray's rim step is looked for this far either side of the circle: the best circle of a refused
# frame lies up to about 2 px inside a faint rim.
RIM_PX = 2.0
# An answered frame whose rim is found on fewer rays than min_support plus this share is told it
# has little margin: a little less light or a busier backdrop and the frame would be refused.
MARGIN = 0.15

COLOURS = {"rim": (0, 200, 0), "faint": (0, 0, 255), "crowded": (0, 165, 255), "outside": (128, 128, 128)}
DIRECTIONS = ["right", "lower right", "below", "lower left", "left", "upper left", "above", "upper right"]


def direction(deg):
    """The side of the circle at angle deg (x right, y down): right, lower right, below, ..."""
    return DIRECTIONS[int(math.floor((deg % 360.0) / 45.0 + 0.5)) % 8]


def ray_kinds(img, circle, p):
    """Per ray of the circle: rim, faint, crowded or outside (see the module's help), from the
    rays the finder casts for the circle's support: the colour step along each (the largest over
    B, G, R of the difference of samples 1 px apart, every half pixel from support_flank_px inside
    to support_flank_px outside), and whether it leaves the frame."""
    cx, cy, r = circle[:3]
    flank = p["support_flank_px"]
    rho, step, outside = pp._ray_scores(img, pp._ray_dirs(p["rays"]), cx, cy, r, flank)
    found = pp.rim_support(img, circle, p)
    d = rho[1:-1] - r
    at_rim = step[:, np.abs(d) <= RIM_PX].max(axis=1)
    past = d >= RIM_PX + 0.5
    beyond = step[:, past].max(axis=1) if past.any() else np.zeros(len(found))
    crowded = beyond >= np.maximum(at_rim, p["support_edge_min"])
    return ["rim" if found[i] else "outside" if outside[i] else "crowded" if crowded[i] else "faint"
            for i in range(len(found))]


def arcs(kinds, kind):
    """Runs of at least 3 consecutive rays of one kind, around the circle: [(first, last)] as
    angles in degrees (last may exceed 360), the longest first."""
    k = len(kinds)
    if not kinds:
        return []
    if all(x == kind for x in kinds):
        return [(0.0, 360.0)]
    start = next(i for i in range(k) if kinds[i] != kind)  # begin after a ray of another kind
    runs, i = [], 0
    while i < k:
        j = (start + i) % k
        if kinds[j] != kind:
            i += 1
            continue
        n = 0
        while i + n < k and kinds[(start + i + n) % k] == kind:
            n += 1
        if n >= 3:
            runs.append((j * 360.0 / k, (j + n - 1) * 360.0 / k))
        i += n
    return sorted(runs, key=lambda a: a[0] - a[1])


def where(kinds, kind):
    """Where the two longest arcs of a kind lie, in words ('left and below'; 'all round' for the
    whole circle; '' without one)."""
    if kinds and all(x == kind for x in kinds):
        return "all round"
    sides = []
    for a, b in arcs(kinds, kind)[:2]:
        s = direction((a + b) / 2.0)
        if s not in sides:
            sides.append(s)
    return " and ".join(sides)


def share(kinds, kind):
    return sum(x == kind for x in kinds) / len(kinds)


def best_fit(fits, img, p, camera):
    """The best supported fit of a radius the sphere may have (first on ties), or None."""
    h, w = img.shape[:2]
    rmin, rmax = pp.radius_range(h, w, p, camera)
    sized = [f for f in fits if pp._sized(f[2], rmin, rmax)]
    return max(sized, key=lambda f: f[3]) if sized else None


def wrong_size(img, p, camera):
    """When the camera file's expected radius hides the sphere: the circle found searching at any
    size, if its radius lies outside the expected range and its rim is found on at least the
    decisive share of its rays (a clear circle, not a checkerboard's or clutter's); else None."""
    if camera is None:
        return None
    h, w = img.shape[:2]
    rmin, rmax = pp.radius_range(h, w, p, camera)
    try:
        c = pp.find_sphere(img, p, None)[:3]
    except pp.NoSphere:
        return None
    if rmin <= c[2] <= rmax or pp.rim_support(img, c, p).mean() < pp._decisive_support(p):
        return None
    return c


def advice(error, circle, support, kinds, p, img, camera):
    """What to change on the rig, as a list of sentences."""
    need = p["min_support"]
    if error is None:
        if support >= need + MARGIN:
            return []
        return [f"little margin: a frame is refused below {100 * need:.0f} %; " + cause(kinds)]
    if error.startswith("sphere cut by the frame edge"):
        return ["move the sphere or the camera so that the whole sphere is in the frame"]
    if error.startswith("two spheres"):
        return ["keep one sphere-sized round object in view: move or cover the other one"]
    other = wrong_size(img, p, camera)
    if other is not None:
        h, w = img.shape[:2]
        rmin, rmax = pp.radius_range(h, w, p, camera)
        return [f"a circle of radius {other[2]:.1f} px at ({other[0] + 0.5:.1f}, {other[1] + 0.5:.1f}) is "
                f"found when any size is allowed, but the camera file expects {rmin:.1f}-{rmax:.1f} px: "
                f"check its distance_mm, focal_mm, pixel_mm and sphere_diameter_mm"]
    if circle is None:
        return ["nothing round of the sphere's size stands out: is the sphere in view, in focus and lit?"]
    # The best circle of a frame without the sphere is clutter's, found on 2-32 % of its rays on the
    # ray-caster's frames; a refused clear sphere's on 24-41 % (docs/bench/localise.md): the share
    # cannot tell them apart, the drawing can
    return [f"if the best circle lies on your sphere, a frame needs {100 * need:.0f} %: " + cause(kinds),
            "if it does not, the sphere was not found at all: is it in view, lit, and of the size the camera file "
            "expects?"]


def cause(kinds):
    """Why rays miss the rim, the larger share first."""
    faint, crowded = share(kinds, "faint"), share(kinds, "crowded")
    parts = []
    for s, kind, text in sorted(((faint, "faint", "the rim is faint"),
                                 (crowded, "crowded", "another edge lies at the rim")), reverse=True):
        if s < 0.05:
            continue
        at = where(kinds, kind)
        parts.append(f"{text} on {100 * s:.0f} % of the rays" + (f" ({at})" if at else ""))
    if not parts:
        return "the rim is found where the sphere is in the frame"
    text = "; ".join(parts)
    if faint >= crowded:
        return (text + ": the sphere's edge and the backdrop beyond it are alike there, or the edge is "
                "blurred; light the sphere's edge, or use a backdrop darker or brighter than it, and keep the "
                "edge sharp (focus, a shorter exposure)")
    return text + ": the mount, clutter or a shadow touching the sphere; a plainer backdrop near the sphere"


def check(frame, p, camera):
    """The finder's view of one BGR frame: a dict (see --json)."""
    img = pp.undistort(frame, camera) if camera is not None else pp._as_bgr(frame)
    fits = []
    try:
        cx, cy, r, _ = pp.find_sphere(img, p, camera, fits)
        error, circle = None, (cx, cy, r)
    except pp.NoSphere as e:
        error = str(e)
        b = best_fit(fits, img, p, camera)
        circle = None if b is None else tuple(b[:3])
    kinds = ray_kinds(img, circle, p) if circle is not None else []
    support = share(kinds, "rim") if kinds else 0.0
    return {"answered": error is None, "error": error,
            "circle": None if circle is None else [round(circle[0] + 0.5, 3), round(circle[1] + 0.5, 3),
                                                   round(circle[2], 3)],
            "rim": round(support, 3), "faint": round(share(kinds, "faint"), 3) if kinds else None,
            "crowded": round(share(kinds, "crowded"), 3) if kinds else None,
            "outside": round(share(kinds, "outside"), 3) if kinds else None,
            "advice": advice(error, circle, support, kinds, p, img, camera), "_img": img, "_kinds": kinds}


def overlay(res, path):
    """Write the frame with the circle and its rays' ticks to path (through a temporary name)."""
    img = res["_img"].copy()
    c = res["circle"]
    if c is not None:
        cx, cy, r = c[0] - 0.5, c[1] - 0.5, c[2]  # OpenCV's pixel centres
        colour = (255, 255, 0) if res["answered"] else (255, 0, 255)
        cv2.circle(img, (round(cx * 16), round(cy * 16)), round(r * 16), colour, 1, cv2.LINE_AA, 4)
        k = len(res["_kinds"])
        for i, kind in enumerate(res["_kinds"]):
            a = 2.0 * math.pi * i / k
            p0 = (cx + (r + 3) * math.cos(a), cy + (r + 3) * math.sin(a))
            p1 = (cx + (r + 9) * math.cos(a), cy + (r + 9) * math.sin(a))
            cv2.line(img, (round(p0[0] * 16), round(p0[1] * 16)), (round(p1[0] * 16), round(p1[1] * 16)),
                     COLOURS[kind], 2, cv2.LINE_AA, 4)
    # the words below the frame, not over it
    text = wrap([summary(res)] + res["advice"], max(20, img.shape[1] // 7))
    h = img.shape[0]
    img = cv2.copyMakeBorder(img, 0, 16 * len(text) + 4, 0, 0, cv2.BORDER_CONSTANT, value=(0, 0, 0))
    for i, line in enumerate(text):
        cv2.putText(img, line, (4, h + 14 + 16 * i), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1,
                    cv2.LINE_AA)
    tmp = f"{path}.tmp{os.getpid()}.png"
    try:
        if not cv2.imwrite(tmp, img):
            raise OSError(f"{path}: cannot write the image")
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def wrap(lines, width):
    out = []
    for line in lines:
        words, cur = line.split(), ""
        for word in words:
            if cur and len(cur) + 1 + len(word) > width:
                out.append(cur)
                cur = word
            else:
                cur = f"{cur} {word}" if cur else word
        out.append(cur)
    return out


def summary(res):
    c = res["circle"]
    at = "" if c is None else (f"circle ({c[0]:.1f}, {c[1]:.1f}) r {c[2]:.1f} px, rim found on "
                               f"{100 * res['rim']:.0f} % of its rays")
    if res["answered"]:
        return f"answered: {at}"
    return f"refused: {res['error']}" + (f"; best {at}" if at else "")


def images(args_images):
    """The image files named (a directory stands for its images, sorted)."""
    out = []
    for a in args_images:
        q = Path(a)
        if q.is_dir():
            out += sorted(f for f in q.iterdir() if f.suffix.lower() in IMAGE_SUFFIXES and f.is_file())
        else:
            out.append(q)
    return out


def usage_error(message):
    print(f"sphere_check: {message}", file=sys.stderr)
    sys.exit(2)


def model_params(path):
    try:
        meta = read_metadata(path)
    except Exception as e:  # onnx raises its own kinds for a missing or corrupt file
        usage_error(f"{path}: cannot read the model ({e})")
    try:
        p = pp.params(meta.get("spherepose.preprocess"), model=str(path))
    except ValueError as e:
        usage_error(str(e))
    if p["name"] != pp.NAME_V2:
        usage_error(f"{path}: preprocessing {p['name']!r}; this check is for {pp.NAME_V2!r}")
    return p


def main(argv=None):
    title, _usage, rest = __doc__.split("\n\n", 2)
    ap = argparse.ArgumentParser(description=f"{title}\n\n{rest}",
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 usage="%(prog)s [--model M.onnx] [--camera-file CAM.json] [--out DIR] [--json] "
                                       "IMAGE|DIR ...")
    ap.add_argument("images", nargs="+", metavar="IMAGE|DIR", help="frames of your camera (PNG, JPEG, ...)")
    ap.add_argument("--model", default=str(MODEL), help="the model whose localisation parameters to use "
                    "(default: the shipped Texture_3_color.onnx)")
    ap.add_argument("--camera-file", help="your camera's file (docs/interfaces.md): the sphere's expected "
                    "size and the lens distortion, as poseinfer --camera-file")
    ap.add_argument("--out", help="write DIR/<name>_check.png for each frame")
    ap.add_argument("--json", action="store_true", help="one JSON object per frame instead of text")
    args = ap.parse_args(argv)
    p = model_params(args.model)
    try:
        camera = load_camera(args.camera_file) if args.camera_file else None
    except CameraError as e:
        usage_error(str(e))
    files = images(args.images)
    if not files:
        usage_error("no image files given")
    if args.out:
        try:
            os.makedirs(args.out, exist_ok=True)
        except OSError as e:
            usage_error(f"{args.out}: cannot make the folder: {e.strerror}")
    answered, refused, unchecked, unwritten = [], 0, 0, 0
    names = set()
    for f in files:
        res, why = check_file(f, p, camera)
        if res is None:
            unchecked += 1
            print(json.dumps({"file": str(f), "error": why}) if args.json else f"{f}: {why}", flush=True)
            continue
        if res["answered"]:
            answered.append(res["rim"])
        else:
            refused += 1
        if args.out:
            try:
                overlay(res, os.path.join(args.out, drawing_name(f, names)))
            except (OSError, cv2.error) as e:
                unwritten += 1
                print(f"sphere_check: {f}: cannot write its drawing: {e}", file=sys.stderr, flush=True)
        if args.json:
            print(json.dumps({"file": str(f), **{k: v for k, v in res.items() if not k.startswith("_")}}), flush=True)
        else:
            print("\n    ".join([f"{f}: {summary(res)}"] + res["advice"]), flush=True)
    if len(files) > 1 and not args.json:
        thin = sum(1 for v in answered if v < p["min_support"] + MARGIN)
        lo, hi = (f"{100 * v:.0f}" for v in (min(answered), max(answered))) if answered else ("", "")
        shares = (f" (rim found on {lo if lo == hi else f'{lo}-{hi}'} % of the rays"
                  + (f"; {thin} with little margin)" if thin else ")")) if answered else ""
        print(f"{len(files)} frames: {len(answered)} answered{shares}, {refused} refused, {unchecked} not checked")
    return 1 if refused or unchecked or unwritten else 0


def check_file(path, p, camera):
    """(check() of an image file, None), or (None, why) when it cannot be decoded or is not of the
    camera file's size."""
    frame = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if frame is None or frame.dtype != np.uint8:
        return None, "cannot decode image (missing, corrupt or not an 8-bit image)"
    if camera is not None:
        try:
            pp._check_size(frame, camera)
        except ValueError as e:
            return None, str(e)
    return check(frame, p, camera), None


def drawing_name(path, names):
    """<stem>_check.png, or <stem>_2_check.png, ... when an earlier frame of the run took it (a.png
    and a.jpg, or one name in two folders)."""
    name, n = f"{path.stem}_check.png", 1
    while name in names:
        n += 1
        name = f"{path.stem}_{n}_check.png"
    names.add(name)
    return name


if __name__ == "__main__":
    sys.exit(main())
