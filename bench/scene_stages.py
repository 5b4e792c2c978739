#!/usr/bin/env python3
"""CPU time per stage of a rig-scene frame (sim/scene_render.py), one process, one thread.

Runs the stages of SceneRenderer.render one by one on N frames of a scene's
draw (as a dataset worker does: one llvmpipe thread, no OpenCV thread pool)
and prints the mean CPU milliseconds of each: the draw, the VTK pass with
the lens remap (and the remap timed again alone), the background, the camera effects, the JPEG round trip and the
PNG encoding of the finished frame.

    .venv/bin/python bench/scene_stages.py [--scene sim/scenes/train.json] [--texture PNG] [--frames 40]
"""
import os

os.environ.setdefault("LP_NUM_THREADS", "1")  # as in a dataset worker

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from sim.frames import encode_png  # noqa: E402
from sim.lens import distort  # noqa: E402
from sim.render import Light  # noqa: E402
from sim.scene import draw, load_scene  # noqa: E402
from sim.scene_background import make_background  # noqa: E402
from sim.scene_effects import finish  # noqa: E402
from sim.scene_render import SceneRenderer  # noqa: E402


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", default="sim/scenes/train.json", help="scene file (default: %(default)s)")
    p.add_argument("--texture", default="build/textures/Texture_3_color.png", help="texture (default: %(default)s)")
    p.add_argument("--frames", type=int, default=40, help="frames to time (default: %(default)s)")
    args = p.parse_args(argv)
    cv2.setNumThreads(1)
    scene = load_scene(args.scene)
    sr = SceneRenderer(args.texture, scene)
    cam = sr.camera
    m = sr.renderer.margin
    blank = np.zeros((cam.height + 2 * m, cam.width + 2 * m, 4), np.uint8)
    acc = {}

    def tick(name, t0):
        t = time.process_time()
        acc[name] = acc.get(name, 0.0) + t - t0
        return t

    for i in range(args.frames + 1):
        if i == 1:
            acc = {}  # the first frame warms caches and the GL pipeline
        t = time.process_time()
        prm = draw(scene, np.random.default_rng([0, 2, i]))
        t = tick("draw", t)
        c = prm["camera"]
        sr.renderer.set_material(**prm["sphere"])
        sr.mount.set(prm["mount"], cam.radius_mm)
        lights = tuple(Light(tuple(l["direction"]), l["intensity"], tuple(l["color"])) for l in prm["lights"])
        rgba = sr.renderer.render((i % 30, 2.0, 3.0), lights=lights, background=(0, 0, 0),
                                  offset_px=prm["offset_px"], scale=c["focal_px"] / cam.focal_px,
                                  distance_mm=c["distance_mm"], principal=c["principal_px"],
                                  distortion=c["distortion"])
        t = tick("VTK pass (sphere, mount, lights; RGBA) and lens remap", t)
        if any(c["distortion"]):  # the remap alone again, on an image of the pinhole pass's size
            distort(blank, c["focal_px"], c["principal_px"], c["distortion"], margin=m)
        t = tick("  of which the lens remap (timed again alone)", t)
        bg = make_background(prm["background"], scene.background, scene.photos, cam.width, cam.height)
        t = tick("background", t)
        im = dict(prm["image"], jpeg_quality=None)
        out = finish(rgba, bg, im, c["principal_px"])
        t = tick("composite, blur, vignetting, exposure, noise, gamma", t)
        if prm["image"]["jpeg_quality"] is not None:
            ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, prm["image"]["jpeg_quality"]])
            out = cv2.imdecode(buf, cv2.IMREAD_COLOR)
        t = tick("JPEG round trip", t)
        encode_png(out)
        tick("PNG encoding", t)
    n = args.frames
    print(f"scene_stages: {args.scene}, {n} frames, {cam.width} x {cam.height}, CPU ms per frame")
    for k, v in acc.items():
        print(f"  {k:55s} {1000 * v / n:6.1f}")
    total = sum(v for k, v in acc.items() if not k.startswith("  "))
    print(f"  {'total':55s} {1000 * total / n:6.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
