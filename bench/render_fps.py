#!/usr/bin/env python3
"""Frames per second of `sim dataset` for protocol P1 at the reference camera, 1 worker vs N workers.

Renders the P1 pose plan (train 1600, val 597, test 100, off-grid test 100:
2397 frames, written as PNG exactly as `sim dataset` writes them) once with
one worker and once with every core, into temporary folders, and prints the
frame rates and their ratio. The two runs happen in the same invocation, so
their ratio holds even when the machine is shared and absolute numbers move.

    .venv/bin/python bench/render_fps.py [--texture PNG] [--frames N] [--workers N] [--json FILE]
    .venv/bin/python bench/render_fps.py --scene sim/scenes/train.json ...   # the plain frames, then the scene's

With --scene the same plan is also rendered with that rig scene (sim dataset
--scene), 1 worker and N workers, in the same invocation as the plain frames.

Without --texture it uses a synthetic 2048 x 1024 stand-in in the paper's
colours (black, white, green, blue stripes and patches).
"""
import argparse
import json
import os
import shutil
import sys
import tempfile
import time

import numpy as np
from PIL import Image

from machine import load_1min, machine
from sim.dataset import DatasetConfig, build


def synthetic_texture(path, h=1024):
    """A Texture_3_color-like stand-in: stripes and patches of black, white, green and blue."""
    w = 2 * h
    tex = np.full((h, w, 3), 255, np.uint8)
    green, blue = (0, 125, 50), (30, 40, 200)
    for k, row in enumerate(range(h // 16, h, h // 8)):
        tex[row:row + h // 20] = (0, 0, 0) if k % 2 else green
    for k, col in enumerate(range(0, w, w // 12)):
        tex[:, col:col + w // 40] = blue if k % 3 == 0 else (0, 0, 0)
    rng = np.random.default_rng(0)
    for _ in range(40):
        r, c = rng.integers(0, h - 40), rng.integers(0, w - 120)
        tex[r:r + 20, c:c + 120] = (0, 0, 0) if rng.random() < 0.5 else green
    Image.fromarray(tex).save(path)
    return path


def run(texture, frames, workers, tmp, scene=None):
    counts = {"train": 1600, "val": 597, "test": 100, "test_offgrid": 100}
    # Keep the P1 proportions when only part of the plan is rendered.
    scale = min(1.0, frames / sum(counts.values()))
    counts = {k: int(round(v * scale)) for k, v in counts.items()}
    out = os.path.join(tmp, f"w{workers}{'-scene' if scene else ''}")
    cfg = (DatasetConfig(texture=texture, counts=counts) if scene is None
           else DatasetConfig(texture=texture, counts=counts, camera=scene.camera, scene=scene))
    t0, c0 = time.perf_counter(), time.process_time()
    rec = build(cfg, out, workers=workers, progress=False, command="bench/render_fps.py", log=lambda *a: None)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    n = rec["last_run"]["rendered"]
    shutil.rmtree(out)
    res = {"workers": workers, "frames": n, "seconds": round(wall, 3), "frames_per_s": round(n / wall, 1)}
    if workers == 1:
        # One worker renders in this process: its CPU time per frame does not depend on
        # what else the machine runs, and bounds what each core can do.
        res["cpu_ms_per_frame"] = round(1000.0 * cpu / n, 2)
    return res


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--texture", help="texture PNG (default: a synthetic stand-in in the paper's colours)")
    p.add_argument("--frames", type=int, default=2397, help="frames per run (default: 2397, the whole P1 plan)")
    p.add_argument("--workers", type=int, default=len(os.sched_getaffinity(0)),
                   help="workers of the parallel run (default: every core)")
    p.add_argument("--json", help="also write the results to this JSON file")
    p.add_argument("--scene", help="also render the plan with this rig scene file (sim dataset --scene)")
    args = p.parse_args(argv)
    scene = None
    if args.scene:
        from sim.scene import load_scene
        scene = load_scene(args.scene)
    load_before = load_1min()
    with tempfile.TemporaryDirectory(prefix="render_fps-") as tmp:
        texture = args.texture or synthetic_texture(os.path.join(tmp, "synthetic.png"))
        one = run(texture, args.frames, 1, tmp)
        many = run(texture, args.frames, args.workers, tmp)
        if scene is not None:
            scene_one = run(texture, args.frames, 1, tmp, scene)
            scene_many = run(texture, args.frames, args.workers, tmp, scene)
    result = {
        **machine(),
        "texture": os.path.basename(args.texture) if args.texture else "synthetic 2048x1024",
        "camera": "reference 640x512",
        "one_worker": one, "parallel": many,
        "speedup": round(many["frames_per_s"] / one["frames_per_s"], 2),
        "load_average_1min": [round(load_before, 2), round(load_1min(), 2)],  # before, after
    }
    print(f"render_fps: {one['frames']} frames, P1 plan, reference camera, nproc {result['nproc']} ({result['cpu']})")
    print(f"  1 worker : {one['frames_per_s']:7.1f} frames/s ({one['seconds']} s; "
          f"{one['cpu_ms_per_frame']} ms CPU per frame = {1000 / one['cpu_ms_per_frame']:.0f} frames/s per idle core)")
    print(f"  {many['workers']} workers: {many['frames_per_s']:7.1f} frames/s ({many['seconds']} s)")
    print(f"  speed-up : {result['speedup']:.2f}x (1-min load average before/after: "
          f"{result['load_average_1min'][0]} / {result['load_average_1min'][1]})")
    if scene is not None:
        result["scene"] = {"file": args.scene, "one_worker": scene_one, "parallel": scene_many}
        print(f"  scene {args.scene}:")
        print(f"  1 worker : {scene_one['frames_per_s']:7.1f} frames/s ({scene_one['seconds']} s; "
              f"{scene_one['cpu_ms_per_frame']} ms CPU per frame)")
        print(f"  {scene_many['workers']} workers: {scene_many['frames_per_s']:7.1f} frames/s "
              f"({scene_many['seconds']} s); plain / scene: "
              f"{many['frames_per_s'] / scene_many['frames_per_s']:.1f}x")
        result["load_average_1min"][1] = round(load_1min(), 2)
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(result, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
