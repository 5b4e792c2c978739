"""Refinement and confidence of a model on labelled frame folders, through poseinfer.

For each folder (frames named <x>_<y>_<z>.png, as `sim dataset` and `python -m bench.raycast`
write them): the network's and the refined errors (mean over frames and axes of |wrapped
difference|, and the largest on one axis), the share of frames flagged (not confident) and why,
the residuals, and refinement's time beside the network's (CPU when poseinfer runs alone; the
`refine_ms` and `infer_ms` it prints). A markdown table on stdout (docs/refine.md has the
readings):

    .venv/bin/python bench/refine_eval.py --model training/models/Texture_3_color.onnx DIR...
    .venv/bin/python bench/refine_eval.py --model M --no-refine DIR...

The corners of the pose range (issue 11: all three angles within 3 deg of +-30 deg) are not a
family of the independent ray-caster; `--corners FAMILY --out DIR` renders such frames with it
(its scene of FAMILY, the pose replaced by one drawn in a corner: each angle's magnitude uniform
in [27, 30], the eight sign patterns in turn) and then evaluates them like any folder:

    .venv/bin/python bench/refine_eval.py --model M --camera-file C --corners clean --n 40 --seed 7 --out DIR
"""
import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sim.names import parse_name  # noqa: E402


def wrap(a):
    return (np.asarray(a, np.float64) + 180.0) % 360.0 - 180.0


CORNER_LO, CORNER_HI = 27.0, 30.0   # |angle| of a corner pose (the range is +-30)


def render_corners(family, n, seed, out, texture, camera_file=None):
    """n frames of the ray-caster's `family` with corner poses into `out` (<x>_<y>_<z>.png and
    truth.jsonl, as bench/raycast writes them). Frame i: the family's scene i for `seed`, the
    pose's signs the bits of i, its magnitudes drawn from the seed and i."""
    sys.path.insert(0, str(ROOT / "bench"))
    import cv2
    from raycast import camera, families, frames, render
    cam = camera.load_camera(camera_file)
    tex = render.load_texture(texture)
    out = Path(out)
    params = {"corners": family, "n": n, "seed": seed, "texture": frames.texture_record(texture),
              "camera": cam.to_dict()}
    try:
        if frames.reuse_or_clear(str(out), params):
            return out       # rendered before with the same parameters
    except frames.FolderError as e:
        raise SystemExit(f"refine_eval: {e}")
    truths = []
    for i in range(n):
        scene = families.draw_scene(family, seed, i, cam)
        rng = np.random.default_rng([7, seed, i])
        signs = [1.0 if (i >> k) & 1 else -1.0 for k in range(3)]
        scene["pose"] = [round(s * float(rng.uniform(CORNER_LO, CORNER_HI)), 3) for s in signs]
        img = render.render(scene, cam, tex)
        name = frames.frame_name(scene["pose"])
        if not cv2.imwrite(str(out / name), cv2.cvtColor(img, cv2.COLOR_RGB2BGR)):
            raise SystemExit(f"refine_eval: {out / name}: cannot write")
        circle = [round(c, 4) for c in render.circle(scene, cam)]
        truths.append({"file": name, "pose": scene["pose"], "circle": circle, "scene": scene})
    frames.finish_folder(str(out), params, truths)
    return out


def run_folder(exe, model, folder, extra):
    files = sorted(str(p) for p in Path(folder).iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
    if not files:
        raise SystemExit(f"refine_eval: {folder}: no frames")
    proc = subprocess.run([str(exe), "--model", str(model), "--timings", *extra, *files],
                          capture_output=True, text=True)
    if proc.returncode not in (0, 1):
        raise SystemExit(f"refine_eval: poseinfer failed: {proc.stderr.strip()}")
    rows = [json.loads(line) for line in proc.stdout.splitlines()]
    ok = [r for r in rows if "error" not in r]
    truth = np.array([parse_name(r["file"]) for r in ok], np.float64)
    est = np.array([[r["x"], r["y"], r["z"]] for r in ok])
    net = np.array([r["net"] for r in ok])
    e, en = np.abs(wrap(est - truth)), np.abs(wrap(net - truth))
    flagged = np.array([r["confident"] is not True for r in ok])
    notes = {}
    for r in ok:
        if r.get("note"):
            k = r["note"].split(" (")[0]
            notes[k] = notes.get(k, 0) + 1
    res = np.array([r["residual"] if r["residual"] is not None else np.nan for r in ok])
    return {"folder": str(folder), "n": len(rows), "failed": len(rows) - len(ok),
            "net_mae": float(en.mean()), "mae": float(e.mean()), "max": float(e.max()),
            "flagged": float(flagged.mean()), "notes": notes,
            "mae_confident": float(e[~flagged].mean()) if (~flagged).any() else float("nan"),
            "max_confident": float(e[~flagged].max()) if (~flagged).any() else float("nan"),
            "residual_median": float(np.nanmedian(res)), "residual_max": float(np.nanmax(res)),
            "refine_ms_p50": float(np.median([r["refine_ms"] for r in ok])),
            "infer_ms_p50": float(np.median([r["infer_ms"] for r in ok]))}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--model", required=True, help="ONNX model (with its texture for refinement)")
    ap.add_argument("--poseinfer", default=os.environ.get("POSEINFER", str(ROOT / "host" / "build" / "poseinfer")),
                    help="the poseinfer binary")
    ap.add_argument("--no-refine", action="store_true", help="judge the network's angles, unrefined")
    ap.add_argument("--camera-file", default=None, help="camera file given to poseinfer (a sphere-crop-v2 "
                    "model reads the expected sphere size from it; also the camera --corners renders with)")
    ap.add_argument("--json", action="store_true", help="one JSON object per folder instead of the table")
    ap.add_argument("--corners", default=None, metavar="FAMILY",
                    help="first render --n frames of this ray-caster family with corner poses into --out")
    ap.add_argument("--out", default=None, help="folder for --corners (evaluated after the others)")
    ap.add_argument("--n", type=int, default=40, help="frames for --corners")
    ap.add_argument("--seed", type=int, default=0, help="seed for --corners")
    ap.add_argument("--texture", default=str(ROOT / "build" / "textures" / "Texture_3_color.png"),
                    help="texture for --corners")
    ap.add_argument("folders", nargs="*", help="folders of labelled frames")
    args = ap.parse_args(argv)
    extra = ["--no-refine"] if args.no_refine else []
    if args.camera_file:
        extra += ["--camera-file", args.camera_file]
    if args.corners:
        if not args.out or args.n < 1:
            ap.error("--corners needs --out and --n >= 1")
        args.folders.append(str(render_corners(args.corners, args.n, args.seed, args.out, args.texture,
                                               args.camera_file)))
    if not args.folders:
        ap.error("give folders of labelled frames, or --corners")
    out = [run_folder(args.poseinfer, args.model, f, extra) for f in args.folders]
    if args.json:
        for o in out:
            print(json.dumps(o))
        return 0
    print(f"model `{args.model}`{' --no-refine' if args.no_refine else ''}\n")
    print("| frames | n | failed | network MAE | refined MAE | max | confident: MAE / max | flagged | notes | "
          "residual median / max |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- | ---: |")
    for o in out:
        notes = ", ".join(f"{k}: {v}" for k, v in o["notes"].items()) or "–"
        print(f"| {o['folder']} | {o['n']} | {o['failed']} | {o['net_mae']:.3f}° | {o['mae']:.3f}° | {o['max']:.2f}° | "
              f"{o['mae_confident']:.3f}° / {o['max_confident']:.2f}° | "
              f"{100 * o['flagged']:.1f} % | {notes} | {o['residual_median']:.4f} / {o['residual_max']:.4f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
