"""What each stage of the rig-sensor pipeline costs: the same frames with one stage left out at a time.

    .venv/bin/python bench/sensor_stages.py --seed 601 --n 100 --out build/sensor/stages_s601

For frames 0..n-1 of `rig-sensor` (bench/raycast/families.py) it traces each
frame's radiance once, then runs bench/raycast/sensor.py's pipeline on it
several times: `all` (the family's frame, byte for byte), `no-ca`, `no-cfa`
(no mosaic and no demosaicing), `no-wb`, `no-sharpen`, and `none` (all four
left out). Each variant gets its own folder under --out with the frames and
the family's truth.jsonl, ready for bench/localise.py --set NAME=DIR/truth.jsonl@OUT/camera.json.
The family's draws do not change: only this script leaves stages out. The
folders follow bench/raycast's rules (frames.py): a folder with PNG files and
no params.json, or an OUT/camera.json of another camera, is left alone; a
complete folder made with the same parameters is reused.
"""
import argparse
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from raycast import camera, cli, families, frames, render, sensor  # noqa: E402

VARIANTS = {"all": (), "no-ca": ("ca",), "no-cfa": ("cfa",), "no-wb": ("wb",), "no-sharpen": ("sharpen",),
            "none": sensor.STAGES}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--seed", type=int, required=True, help="seed of the rig-sensor frames")
    ap.add_argument("--n", type=int, default=100, help="frames")
    ap.add_argument("--out", required=True, help="output folder (one sub-folder per variant)")
    cli.add_scene_arguments(ap)
    args = ap.parse_args(argv)
    if args.n < 1 or args.supersample < 1:
        sys.exit("sensor_stages: --n and --supersample must be at least 1")
    cam = cli.load_camera(args, "sensor_stages")
    try:
        write_stages(args.out, args.seed, args.n, cam, args.texture, args.supersample)
    except frames.FolderError as e:
        sys.exit(f"sensor_stages: {e}")
    print(f"{args.out}: {args.n} frames x {len(VARIANTS)} variants ({', '.join(VARIANTS)})")


def _claim_camera(out, cam):
    """OUT/camera.json, the variants' camera: written when absent, kept when the same; another
    camera's file there (a measurement folder's, say) is not this tool's to replace."""
    path = os.path.join(out, "camera.json")
    text = json.dumps(cam.to_dict(), indent=1)
    if os.path.exists(path):
        try:
            same = camera.load_camera(path) == cam
        except camera.CameraFileError:
            same = False
        if not same:
            raise frames.FolderError(f"{path}: another camera's file; not replacing it: choose an empty "
                                     f"or new folder, or pass that camera with --camera")
        return
    frames.write_atomic(path, text.encode())


def write_stages(out, seed, n, cam, texture_path, supersample):
    """Frames 0..n-1 of rig-sensor for `seed` into OUT/<variant>/ (frames.py's folder rules: each
    variant folder made the tool's own first, truth.jsonl and params.json last, a complete one
    with the same parameters reused) and OUT/camera.json."""
    os.makedirs(out, exist_ok=True)
    _claim_camera(out, cam)
    base = {"family": "rig-sensor", "n": n, "seed": seed, "camera": cam.to_dict(),
            "texture": frames.texture_record(texture_path), "supersample": supersample, "version": 1}
    params = {v: dict(base, stages_off=list(off)) for v, off in VARIANTS.items()}
    todo = [v for v in VARIANTS if not frames.reuse_or_clear(os.path.join(out, v), params[v])]
    if not todo:
        return
    tex = render.load_texture(texture_path)
    truths = []
    for i in range(n):
        scene = families.draw_scene("rig-sensor", seed, i, cam)
        lit = render.optics(render.radiance(scene, cam, tex, supersample), scene, cam)
        truth = frames.truth_line(scene, cam)
        for v in todo:
            png = frames.encode_png(sensor.pipeline(lit, scene, cam, off=VARIANTS[v]))
            frames.write_atomic(os.path.join(out, v, truth["file"]), png)
        truths.append(truth)
    names = [t["file"] for t in truths]
    if len(set(names)) != len(names):
        raise frames.FolderError(f"{out}: two frames drew the same pose; use another seed")
    for v in todo:
        frames.finish_folder(os.path.join(out, v), params[v], truths)


if __name__ == "__main__":
    main()
