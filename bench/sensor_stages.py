"""What each stage of the rig-sensor pipeline costs: the same frames with one stage left out at a time.

    .venv/bin/python bench/sensor_stages.py --seed 601 --n 100 --out build/sensor/stages_s601

For frames 0..n-1 of `rig-sensor` (bench/raycast/families.py) it traces each
frame's radiance once, then runs bench/raycast/sensor.py's pipeline on it
several times: `all` (the family's frame, byte for byte), `no-ca`, `no-cfa`
(no mosaic and no demosaicing), `no-wb`, `no-sharpen`, and `none` (all four
left out). Each variant gets its own folder under --out with the frames and
the family's truth.jsonl, ready for bench/localise.py --set NAME=DIR/truth.jsonl@OUT/camera.json.
The family's draws do not change: only this script leaves stages out.
"""
import argparse
import json
import os
import sys

import cv2

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from raycast import camera, families, frames, render, sensor  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
VARIANTS = {"all": (), "no-ca": ("ca",), "no-cfa": ("cfa",), "no-wb": ("wb",), "no-sharpen": ("sharpen",),
            "none": sensor.STAGES}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--seed", type=int, required=True, help="seed of the rig-sensor frames")
    ap.add_argument("--n", type=int, default=100, help="frames")
    ap.add_argument("--out", required=True, help="output folder (one sub-folder per variant)")
    ap.add_argument("--texture", default=os.path.join(ROOT, "build", "textures", "Texture_3_color.png"),
                    help="equirectangular texture")
    ap.add_argument("--camera", default=None, help="camera file (default: the reference camera)")
    ap.add_argument("--supersample", type=int, default=4, help="rays per pixel per side on the sphere and edges")
    args = ap.parse_args(argv)
    if args.n < 1 or args.supersample < 1:
        sys.exit("sensor_stages: --n and --supersample must be at least 1")
    if not os.path.isfile(args.texture):
        sys.exit(f"sensor_stages: {args.texture}: no such texture (make textures)")
    try:
        cam = camera.load_camera(args.camera)
    except camera.CameraFileError as e:
        sys.exit(f"sensor_stages: {e}")
    tex = render.load_texture(args.texture)
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "camera.json"), "w", encoding="utf-8") as f:
        json.dump(cam.to_dict(), f, indent=1)
    for v in VARIANTS:
        os.makedirs(os.path.join(args.out, v), exist_ok=True)
    truths = []
    for i in range(args.n):
        scene = families.draw_scene("rig-sensor", args.seed, i, cam)
        lit = render.optics(render.radiance(scene, cam, tex, args.supersample), scene, cam)
        name = frames.frame_name(scene["pose"])
        for v, off in VARIANTS.items():
            img = sensor.pipeline(lit, scene, cam, off=off)
            cv2.imwrite(os.path.join(args.out, v, name), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        scene["hidden_rim"] = render.hidden_rim_fraction(scene, cam) if scene.get("mount") else 0.0
        circle = [round(c, 4) for c in render.circle(scene, cam)]
        truths.append({"file": name, "pose": scene["pose"], "circle": circle, "scene": scene})
    lines = "".join(json.dumps(t) + "\n" for t in truths)
    for v in VARIANTS:
        with open(os.path.join(args.out, v, "truth.jsonl"), "w", encoding="utf-8") as f:
            f.write(lines)
    print(f"{args.out}: {args.n} frames x {len(VARIANTS)} variants ({', '.join(VARIANTS)})")


if __name__ == "__main__":
    main()
