"""Sphere localisation accuracy of the preprocessing (sphere-crop-v1 / v2) on rig-like frames.

Frames: the project's VTK renderer (`sim`) draws the sphere at random poses, principal-point
offsets and focal scales on black and on white; training/rigcomposite.py lays it over a
cluttered background with a mounting post (random side, mostly below), vignetting, gamma,
noise and JPEG. The true circle follows from the camera model. Or, with --truth, frames with a
truth.jsonl (sim dataset --scene, or any generator writing that file).

    python bench/localise.py --frames 60 --seed 1 [--camera] [--out frames/]
    python bench/localise.py --truth DIR/truth.jsonl [--camera-file CAM.json]
    python bench/localise.py --set rig=DIR/truth.jsonl@CAM.json --set val=DIR2/truth.jsonl
        --refuse refuse=DIR3/truth.jsonl@CAM.json --jobs 2 [--dump frames.jsonl]

Prints, per algorithm, centre error (px) and radius error (%) median / p95 / max, and how many
frames raised an error. --camera passes the camera (expected radius) to v2.

With --set / --refuse (sphere-crop-v2 only, each frame with its camera: the set's camera file
after "@", else the frame's own from truth.jsonl): one table row per set, with the share of
frames answered, of frames answered within the target (centre <= 0.5 px and radius <= 0.5 %)
and within 2 px / 2 %; a --refuse set counts the frames that raised an error (by the
"refuse" kind of each frame's scene when there is one), since no answer is right there.
"""
import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from training import preprocess as pp  # noqa: E402
from training import rigcomposite as rc  # noqa: E402
from sim.camera import from_truth  # noqa: E402


def composite_frames(n, seed, texture, out=None):
    """Yield (BGR frame, (cx, cy, r) OpenCV coordinates, camera) for n composite rig frames."""
    from sim.camera import Camera
    from sim.render import Renderer, load_texture
    cam = Camera()
    rend = Renderer(load_texture(texture), cam)
    rng = np.random.default_rng(seed)
    R, D = cam.radius_mm, cam.distance_mm
    for i in range(n):
        pose = rng.uniform(-30, 30, 3)
        scale = float(rng.uniform(0.87, 1.13))
        r = cam.focal_px * scale * R / math.sqrt(D * D - R * R)
        du = float(rng.uniform(-(cam.width / 2 - r - 4), cam.width / 2 - r - 4))
        dv = float(rng.uniform(-(cam.height / 2 - r - 4), cam.height / 2 - r - 4)) if cam.height / 2 > r + 4 else 0.0
        on_b = cv2.cvtColor(rend.render(pose, background=(0, 0, 0), offset_px=(du, dv), scale=scale), cv2.COLOR_RGB2BGR)
        on_w = cv2.cvtColor(rend.render(pose, background=(255, 255, 255), offset_px=(du, dv), scale=scale),
                            cv2.COLOR_RGB2BGR)
        cx, cy = cam.width / 2 + du - 0.5, cam.height / 2 + dv - 0.5
        img = rc.rig_frame(on_b, on_w, cx, cy, r, rng)
        if out is not None:
            name = f"rig_{i:04d}.png"
            cv2.imwrite(str(Path(out) / name), img)
            with open(Path(out) / "truth.jsonl", "a") as f:
                f.write(json.dumps({"file": name, "pose": [float(v) for v in pose],
                                    "circle": [cx + 0.5, cy + 0.5, r]}) + "\n")
        yield img, (cx, cy, r), cam.to_dict() | {"_scale": scale}


def truth_frames(path):
    """Frames of a truth.jsonl; the camera of each from its "scene" record when there is one
    (sim dataset --scene: focal length, principal point, distortion, distance)."""
    root = Path(path).parent
    for line in Path(path).read_text().splitlines():
        t = json.loads(line)
        img = cv2.imread(str(root / t["file"]), cv2.IMREAD_COLOR)
        cx, cy, r = t["circle"]
        cam = None
        sc = (t.get("scene") or {}).get("camera")
        if sc:
            cam = {"width": img.shape[1], "height": img.shape[0], **from_truth(sc)}
        yield img, (cx - 0.5, cy - 0.5, r), cam


def _one(job):
    """One frame of a --set / --refuse run: (set, file, kind, error text or None, centre err, radius err %)."""
    name, root, t, cam_file = job
    img = cv2.imread(str(Path(root) / t["file"]), cv2.IMREAD_COLOR)
    cam = cam_file
    sc = (t.get("scene") or {}).get("camera")
    if cam is None and sc:
        cam = {"width": img.shape[1], "height": img.shape[0], **from_truth(sc)}
    p = pp.params(os.environ.get("SPHEREPOSE_PP_OVERRIDE") or None)
    kind = (t.get("scene") or {}).get("refuse")
    try:
        frame = pp.undistort(img, cam) if cam is not None else img
        fx, fy, fr, _ = pp.find_sphere(frame, p, cam)
    except pp.NoSphere as e:
        return name, t["file"], kind, str(e), None, None
    if not t.get("circle"):
        return name, t["file"], kind, None, None, None
    cx, cy, r = t["circle"]
    return name, t["file"], kind, None, math.hypot(fx - (cx - 0.5), fy - (cy - 0.5)), abs(fr / r - 1) * 100


def run_sets(sets, refuse, jobs, dump):
    """The --set / --refuse measurement: one row per set (see the module's help)."""
    import multiprocessing
    work = []
    for spec, is_refuse in [(s, False) for s in sets] + [(s, True) for s in refuse]:
        name, _, rest = spec.partition("=")
        path, _, camf = rest.partition("@")
        if not path:
            raise SystemExit(f"--set/--refuse {spec!r}: expected NAME=TRUTH.jsonl[@CAMERA.json]")
        cam = json.loads(Path(camf).read_text()) if camf else None
        root = Path(path).parent
        for line in Path(path).read_text().splitlines():
            work.append(((name, is_refuse), (name, str(root), json.loads(line), cam)))
    t0 = time.perf_counter()
    with multiprocessing.Pool(max(1, jobs)) as pool:
        out = pool.map(_one, [w for _, w in work], chunksize=4)
    secs = time.perf_counter() - t0
    if dump:
        with open(dump, "w") as f:
            for (name, _), (_, file, kind, err, ec, er) in zip(work, out):
                f.write(json.dumps({"set": name, "file": file, "kind": kind, "error": err,
                                    "centre_px": ec, "radius_pct": er}) + "\n")
    print("| frames | n | answered | within 0.5 px and 0.5 % | within 2 px and 2 % | "
          "centre px median / p95 / max | radius % median / p95 / max |")
    print("| --- | ---: | ---: | ---: | ---: | --- | --- |")
    names = list(dict.fromkeys(k for k, _ in work))
    for name, is_refuse in names:
        rows = [o for (k, _), o in zip(work, out) if k == (name, is_refuse)]
        n = len(rows)
        if is_refuse:
            kinds = sorted({str(o[2]) for o in rows})
            parts = []
            for kd in kinds:
                rk = [o for o in rows if str(o[2]) == kd]
                parts.append(f"{kd} {sum(o[3] is not None for o in rk)}/{len(rk)}")
            print(f"| {name} (to refuse) | {n} | refused {sum(o[3] is not None for o in rows)} "
                  f"({', '.join(parts)}) | | | | |")
            continue
        ans = [o for o in rows if o[3] is None]
        c = np.array([o[4] for o in ans]) if ans else np.zeros(0)
        r = np.array([o[5] for o in ans]) if ans else np.zeros(0)
        good = int(((c <= 0.5) & (r <= 0.5)).sum())
        ok2 = int(((c <= 2) & (r <= 2)).sum())
        stat = (lambda a: f"{np.median(a):.3f} / {np.percentile(a, 95):.3f} / {a.max():.3f}") if len(ans) else (lambda a: "-")
        print(f"| {name} | {n} | {100 * len(ans) / n:.1f} % | {100 * good / n:.1f} % | {100 * ok2 / n:.1f} % | "
              f"{stat(c)} | {stat(r)} |")
    print(f"({len(work)} frames, {secs:.0f} s with {jobs} processes)")


def summarise(name, errs, fails, n, ms):
    e = np.array(errs) if errs else np.zeros((0, 2))
    if len(e):
        c, rr = e[:, 0], e[:, 1]
        print(f"{name}: {len(e)}/{n} frames; centre px median {np.median(c):.3f} p95 {np.percentile(c, 95):.3f} "
              f"max {c.max():.3f}; radius % median {np.median(rr):.3f} p95 {np.percentile(rr, 95):.3f} "
              f"max {rr.max():.3f}; errors raised {fails}; {ms:.1f} ms/frame (Python)")
    else:
        print(f"{name}: no frame answered; errors raised {fails}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=40, help="composite frames (default 40)")
    ap.add_argument("--seed", type=int, default=1, help="random seed (default 1)")
    ap.add_argument("--texture", default=str(ROOT / "build/textures/Texture_3_color.png"),
                    help="sphere texture (default build/textures/Texture_3_color.png)")
    ap.add_argument("--camera", action="store_true",
                    help="give v2 the camera (expected radius +-15 %%); a lens distortion is always undone")
    ap.add_argument("--truth", help="truth.jsonl of existing frames instead of composites")
    ap.add_argument("--camera-file", help="camera file for --truth frames (undistortion, radius)")
    ap.add_argument("--out", help="also write the composite frames here")
    ap.add_argument("--verbose", action="store_true", help="each frame's errors (stderr)")
    ap.add_argument("--v1", action="store_true", help="measure sphere-crop-v1 too")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=TRUTH[@CAMERA]",
                    help="a frame set to measure (repeatable; see above)")
    ap.add_argument("--refuse", action="append", default=[], metavar="NAME=TRUTH[@CAMERA]",
                    help="a frame set every frame of which must raise an error (repeatable)")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes for --set / --refuse (default 1)")
    ap.add_argument("--dump", help="with --set / --refuse: each frame's result as JSON lines here")
    args = ap.parse_args(argv)
    if args.set or args.refuse:
        run_sets(args.set, args.refuse, args.jobs, args.dump)
        return
    if args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        (Path(args.out) / "truth.jsonl").unlink(missing_ok=True)
    if args.truth:
        frames = truth_frames(args.truth)
    else:
        frames = composite_frames(args.frames, args.seed, args.texture, args.out)
    cam_file = json.loads(Path(args.camera_file).read_text()) if args.camera_file else None
    v2 = pp.params(os.environ.get("SPHEREPOSE_PP_OVERRIDE") or None)  # for trying parameter changes
    algos = [("sphere-crop-v2", v2)] + ([("sphere-crop-v1", pp.params({"name": pp.NAME_V1}))] if args.v1 else [])
    res = {a: ([], 0, 0.0) for a, _ in algos}
    n = 0
    for img, (cx, cy, r), cam in frames:
        n += 1
        if cam_file is not None:
            cam = cam_file
        if cam is not None:
            cam = {k: v for k, v in cam.items() if k != "_scale"}
        for a, p in algos:
            errs, fails, t = res[a]
            t0 = time.perf_counter()
            try:
                if a == "sphere-crop-v2":
                    # a lens's distortion is always undone; its expected radius used with --camera
                    frame = pp.undistort(img, cam) if cam is not None else img
                    fx, fy, fr, _ = pp.find_sphere(frame, p, cam if args.camera or cam_file is not None else None)
                else:
                    fx, fy, fr, _ = pp.find_sphere(img, p)
                errs.append((math.hypot(fx - cx, fy - cy), abs(fr / r - 1) * 100))
                if args.verbose:
                    print(f"frame {n - 1}: {a}: centre {errs[-1][0]:.3f} px, radius {errs[-1][1]:.3f} %", file=sys.stderr)
            except pp.NoSphere as e:
                fails += 1
                print(f"frame {n - 1}: {a}: {e}", file=sys.stderr)
            res[a] = (errs, fails, t + time.perf_counter() - t0)
    for a, _ in algos:
        errs, fails, t = res[a]
        summarise(a, errs, fails, n, 1000 * t / max(1, n))


if __name__ == "__main__":
    main()
