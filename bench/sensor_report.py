r"""The rig-sensor family's readings by stage: docs/bench/realscene.md's tables and slopes from the runs.

    .venv/bin/python bench/sensor_report.py --runs build/sensor/s601 build/sensor/s602 build/sensor/s603 \
        --stages build/sensor/stages_s601 build/sensor/stages_s602 build/sensor/stages_s603

--runs: bench/realscene.py --families rig-sensor --out folders (results.jsonl, the C runtime's poses
and circles; rig-sensor/truth.jsonl, each frame's scene with its "sensor" record; camera.json).
Prints the frames by the value of each pipeline parameter (the largest lateral-colour shift at the
outline, demosaicing, Bayer layout, sharpening, white balance, backdrop), in realscene.py's metrics.

--stages: bench/sensor_stages.py --out folders (one folder per variant: `all`, `no-ca`, ...).
Locates every variant frame with the Python reference (training/preprocess.py's find_sphere after
its undistortion, as bench/localise.py does; equal to the C runtime's) and prints per variant the
circles' errors, the mean change of the centre error against `all` and the frames better / worse by
more than 0.1 px, and the lateral-colour slopes: the centre's radial error (along the line from the
principal point) against the mean red/blue shift of the sphere's centre, ((k_r - 1) + (k_b - 1)) / 2
times its distance from the principal point, and the radius error against the mean red/blue change
of the radius ((k_r - 1) + (k_b - 1)) / 2 r; least squares with an intercept, r Pearson's.
"""
import argparse
import json
import math
import multiprocessing
import os
import sys
import time

import cv2
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "bench"))
sys.path.insert(0, ROOT)

import realscene  # noqa: E402
from training import preprocess as pp  # noqa: E402

VARIANTS = ("all", "no-ca", "no-cfa", "no-wb", "no-sharpen", "none")   # bench/sensor_stages.py's
CHANGE_PX = 0.1            # a frame "better" / "worse" than in `all` by more than this centre error
# The parameters' bands: (heading, [(label, test of the frame's value)])
SHIFT_BANDS = [("< 0.3 px", lambda v: v < 0.3), ("0.3-0.6 px", lambda v: 0.3 <= v < 0.6),
               ("≥ 0.6 px", lambda v: v >= 0.6)]
DEMOSAIC = {"bilinear": "bilinear", "vng": "VNG", "ea": "EA"}
CFA = ("RGGB", "BGGR", "GRBG", "GBRG")
BACKDROPS = ("uniform", "gradient", "clutter")


def _principal(cam):
    return cam.get("principal_px", [cam["width"] / 2.0, cam["height"] / 2.0])


def _read_lines(path):
    try:
        with open(path, encoding="utf-8") as f:
            return [json.loads(line) for line in f if line.strip()]
    except OSError as e:
        sys.exit(f"sensor_report: {path}: {e.strerror}")
    except json.JSONDecodeError as e:
        sys.exit(f"sensor_report: {path}: not JSON lines: {e}")


def _read_json(path):
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except OSError as e:
        sys.exit(f"sensor_report: {path}: {e.strerror}")
    except json.JSONDecodeError as e:
        sys.exit(f"sensor_report: {path}: not valid JSON: {e}")


def shift_at_outline(scene, circle, cam):
    """The largest |k - 1| of red and blue times the outline's farthest distance from the principal point."""
    ca = scene["sensor"]["ca"]
    u0, v0 = _principal(cam)
    return max(abs(ca["red"] - 1.0), abs(ca["blue"] - 1.0)) * (math.hypot(circle[0] - u0, circle[1] - v0) + circle[2])


def stage_values(scene, circle, cam):
    """The frame's value for each row heading of the by-stage table."""
    sen = scene["sensor"]
    shift = shift_at_outline(scene, circle, cam)
    sh = sen.get("sharpen")
    return {"R/B shift at the outline": next(label for label, ok in SHIFT_BANDS if ok(shift)),
            "demosaic": DEMOSAIC[sen["demosaic"]],
            "CFA": sen["cfa"],
            "sharpening": "off" if not sh else ("amount < 0.5" if sh["amount"] < 0.5 else "amount ≥ 0.5"),
            "white balance (max / min gain)": "< 1.25" if max(sen["wb"]) / min(sen["wb"]) < 1.25 else "≥ 1.25",
            "backdrop": scene["background"]["kind"]}


ORDER = {"R/B shift at the outline": [label for label, _ in SHIFT_BANDS], "demosaic": list(DEMOSAIC.values()),
         "CFA": list(CFA), "sharpening": ["off", "amount < 0.5", "amount ≥ 0.5"],
         "white balance (max / min gain)": ["< 1.25", "≥ 1.25"], "backdrop": list(BACKDROPS)}


def _circle_errors(found, truth):
    """Centre error (px) and radius error (%) arrays of matched circles (continuous pixels)."""
    c, t = np.asarray(found, np.float64), np.asarray(truth, np.float64)
    return np.hypot(c[:, 0] - t[:, 0], c[:, 1] - t[:, 1]), 100.0 * np.abs(c[:, 2] - t[:, 2]) / t[:, 2]


def _stats(dc, dr, digits):
    within = int(((dc <= 0.5) & (dr <= 0.5)).sum())
    return (f"{np.median(dc):.{digits}f} / {np.percentile(dc, 95):.{digits}f} / {dc.max():.2f}",
            f"{np.percentile(dr, 95):.2f} / {dr.max():.2f}", within)


def stage_table(rows):
    """The C runtime's results (realscene.py's rows, each with its "scene" and "cam") by stage value."""
    out = ["| stage | value | n | answered / refused | flagged | MAE ° | max ° | centre err median / p95 / max (px) "
           "| radius err p95 / max (%) | within 0.5 px and 0.5 % |",
           "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]

    def line(label, value, grp):
        m = realscene.family_metrics(grp)
        loc = [r for r in grp if r["pred"] is not None and r["found"] is not None]
        cells = ["–", "–", "–"]
        if loc:
            cells = _stats(*_circle_errors([r["found"] for r in loc], [r["circle"] for r in loc]), 2)
        mae = f"{m['mae']:.3f} | {m['max']:.2f}" if "mae" in m else "– | –"
        return (f"| {label} | {value} | {m['n']} | {m['answered']} / {m['n'] - m['answered']} | {m['flagged']} "
                f"| {mae} | {cells[0]} | {cells[1]} | {cells[2]} |")

    out.append(line("all", "", rows))
    for by, values in ORDER.items():
        seen = {}
        for r in rows:
            seen.setdefault(stage_values(r["scene"], r["circle"], r["cam"])[by], []).append(r)
        for k, v in enumerate([v for v in values if v in seen] + sorted(set(seen) - set(values))):
            out.append(line(by if k == 0 else "", v, seen[v]))
    return "\n".join(out)


def _locate(job):
    """One variant frame: (found circle in continuous pixels, or None; the error text, or None)."""
    path, cam = job
    img = cv2.imread(path, cv2.IMREAD_COLOR)
    if img is None:
        return None, f"{path}: cannot read the frame"
    try:
        fx, fy, fr, _ = pp.find_sphere(pp.undistort(img, cam), pp.params(None), cam)
    except pp.NoSphere as e:
        return None, str(e)
    return [fx + 0.5, fy + 0.5, fr], None


def locate_stages(folders, jobs):
    """{variant: [(truth line, camera, found circle or None), ...]} over the folders, frames in order."""
    work, keys = [], []
    for folder in folders:
        cam = _read_json(os.path.join(folder, "camera.json"))
        for v in VARIANTS:
            for t in _read_lines(os.path.join(folder, v, "truth.jsonl")):
                work.append((os.path.join(folder, v, t["file"]), cam))
                keys.append((v, t, cam))
    with multiprocessing.Pool(max(1, jobs)) as pool:
        found = pool.map(_locate, work, chunksize=4)
    out = {v: [] for v in VARIANTS}
    for (v, t, cam), (circle, err) in zip(keys, found):
        if err and err.endswith("cannot read the frame"):
            sys.exit(f"sensor_report: {err}")
        out[v].append((t, cam, circle))
    return out


def slopes(frames):
    """(centre slope, r, radius slope, r) of the lateral-colour regressions over the answered frames."""
    xc, yc, xr, yr = [], [], [], []
    for t, cam, found in frames:
        if found is None:
            continue
        cx, cy, r = t["circle"]
        ca = t["scene"]["sensor"]["ca"]
        k = (ca["red"] - 1.0 + ca["blue"] - 1.0) / 2.0
        u0, v0 = _principal(cam)
        d = math.hypot(cx - u0, cy - v0)
        if d > 0:
            xc.append(k * d)
            yc.append(((found[0] - cx) * (cx - u0) + (found[1] - cy) * (cy - v0)) / d)
        xr.append(k * r)
        yr.append(found[2] - r)
    res = []
    for x, y in ((xc, yc), (xr, yr)):
        x, y = np.asarray(x), np.asarray(y)
        if len(x) < 3 or np.ptp(x) == 0 or np.ptp(y) == 0:
            return None          # too few frames to regress
        res += [float(np.polyfit(x, y, 1)[0]), float(np.corrcoef(x, y)[0, 1])]
    return res


def variant_table(located):
    out = ["| frames | answered / refused | within 0.5 px and 0.5 % | centre err median / p95 / max (px) "
           "| radius err p95 / max (%) | centre error change vs `all`, mean (px) "
           f"| frames better / worse by > {CHANGE_PX} px | slope centre (r) | slope radius (r) |",
           "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    def centre_err(t, c):
        return math.hypot(c[0] - t["circle"][0], c[1] - t["circle"][1])

    for v in VARIANTS:
        frames = located[v]
        ok = [(t, c) for t, _, c in frames if c is not None]
        med, rad, within = "–", "–", 0
        if ok:
            med, rad, within = _stats(*_circle_errors([c for _, c in ok], [t["circle"] for t, _ in ok]), 3)
        change = "– | –"
        if v != "all":     # frames answered in both, the same frames in the same order
            d = np.asarray([centre_err(t, c) - centre_err(t, b)
                            for (t, _, c), (_, _, b) in zip(frames, located["all"]) if c is not None and b is not None])
            if len(d):
                change = f"{d.mean():+.3f} | {int((d < -CHANGE_PX).sum())} / {int((d > CHANGE_PX).sum())}"
        s = slopes(frames)
        fit = "– | –" if s is None else f"{s[0]:.2f} ({s[1]:.2f}) | {s[2]:.2f} ({s[3]:.2f})"
        out.append(f"| {v} | {len(ok)} / {len(frames) - len(ok)} | {within} | {med} | {rad} | {change} | {fit} |")
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", nargs="+", default=[], help="bench/realscene.py --out folders of rig-sensor")
    ap.add_argument("--stages", nargs="+", default=[], help="bench/sensor_stages.py --out folders")
    ap.add_argument("--jobs", type=int, default=1, help="frames located at once (default 1)")
    args = ap.parse_args(argv)
    if not args.runs and not args.stages:
        ap.error("give --runs, --stages or both")
    if args.runs:
        rows = []
        for folder in args.runs:
            cam = _read_json(os.path.join(folder, "camera.json"))
            truth = {t["file"]: t for t in _read_lines(os.path.join(folder, "rig-sensor", "truth.jsonl"))}
            for r in _read_lines(os.path.join(folder, "results.jsonl")):
                if r.get("family") != "rig-sensor":
                    continue
                if r["file"] not in truth:
                    sys.exit(f"sensor_report: {folder}/results.jsonl: {r['file']} is not in rig-sensor/truth.jsonl")
                rows.append(dict(r, scene=truth[r["file"]]["scene"], cam=cam))
        if not rows:
            sys.exit(f"sensor_report: no rig-sensor results in {', '.join(args.runs)}")
        print(f"The C runtime's results by stage ({len(rows)} frames of {', '.join(args.runs)}):\n")
        print(stage_table(rows))
    if args.stages:
        t0 = time.perf_counter()
        located = locate_stages(args.stages, args.jobs)
        n = sum(len(f) for f in located.values())
        print(f"\nThe variants located by training/preprocess.py ({n} frames of {', '.join(args.stages)}, "
              f"{time.perf_counter() - t0:.0f} s):\n")
        print(variant_table(located))


if __name__ == "__main__":
    main()
