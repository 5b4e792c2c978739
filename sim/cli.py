"""`sim`: render one frame, render a dataset, or serve frames as a virtual camera.

    sim render  --texture PNG --pose X Y Z [--camera FILE] [--background R,G,B] [--scene FILE] --out PNG
    sim dataset --texture PNG --out DIR [--scene FILE] [options]
    sim vcam    --texture PNG --socket PATH [--scene FILE] (--stage-state PATH | --pose X Y Z | --pose-file FILE)

See docs/sim.md.
"""
import argparse
import math
import os
import shlex
import sys

from sim.camera import CameraError, load_camera


class _Help(argparse.HelpFormatter):
    """Help that states each option's default, unless the text already does or there is none."""

    def _get_help_string(self, action):
        text = action.help or ""
        if ("default" not in text and action.option_strings and action.default is not None
                and action.default is not False and action.default != argparse.SUPPRESS):
            d = action.default
            shown = ",".join(str(v) for v in d) if isinstance(d, tuple) else "%(default)s"
            text += f" (default: {shown})"
        return text


class UsageError(ValueError):
    """A bad command-line value; the message names the option."""


def _rgb(text):
    parts = text.split(",")
    try:
        vals = [int(p) for p in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected R,G,B integers 0-255, got {text!r}") from None
    if len(vals) != 3 or not all(0 <= v <= 255 for v in vals):
        raise argparse.ArgumentTypeError(f"expected R,G,B integers 0-255, got {text!r}")
    return tuple(vals)


def _finite(text):
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return v


def _pair(text):
    parts = text.split(",")
    if len(parts) != 2:
        raise argparse.ArgumentTypeError(f"expected LO,HI, got {text!r}")
    lo, hi = (_finite(p) for p in parts)
    if lo > hi:
        raise argparse.ArgumentTypeError(f"expected LO <= HI, got {text!r}")
    return (lo, hi)


def _count(text):
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return v


def _load_lights(path):
    from sim.render import lights_from_json
    if path is None:
        return None
    from sim.camera import read_json
    return lights_from_json(read_json(path, "lights file", UsageError), source=str(path))


def _add_scene_args(p):
    p.add_argument("--texture", required=True, metavar="PNG",
                   help="equirectangular texture, width = 2 x height (required)")
    p.add_argument("--camera", metavar="FILE",
                   help="camera JSON (docs/interfaces.md); default: the reference camera "
                        "640x512, f 16 mm, pixel 0.0096 mm, D 250 mm, sphere 40 mm")
    p.add_argument("--background", type=_rgb, metavar="R,G,B",
                   help="background colour (default: 64,64,70, a dark neutral grey apart from "
                        "black, white and the texture colours)")
    p.add_argument("--lights", metavar="FILE",
                   help="lights JSON: a list of {\"direction\": [x,y,z] toward the light, \"intensity\": i, "
                        "\"color\": [r,g,b]} (default: key, fill and rim lights, docs/sim.md)")
    p.add_argument("--scene", metavar="FILE",
                   help="rig scene JSON (docs/sim.md, 'Rig scenes'; e.g. sim/scenes/train.json, sim/scenes/rig.json): "
                        "mount, background, lights, material, lens and camera effects, drawn per frame within "
                        "its ranges; replaces --background, --lights and the randomisation flags; --camera "
                        "replaces the scene's camera")


_RZ_FLAGS = {
    "light_jitter_deg": "light_jitter", "light_intensity": "light_intensity",
    "background_jitter": "background_jitter", "offset_px": "offset", "scale": "scale",
    "exposure": "exposure", "gamma": "gamma", "blur": "blur", "noise": "noise",
}


def _add_randomization_args(p):
    g = p.add_argument_group("domain randomisation (all off by default; --randomize turns on the preset "
                             "for every one not given)")
    g.add_argument("--randomize", action="store_true",
                   help="preset: light jitter 25 deg, light intensity 0.7,1.2, background jitter 20, offset 8 px, "
                        "scale 0.05, exposure 0.8,1.2, gamma 0.85,1.15, blur 1.0, noise 4")
    g.add_argument("--light-jitter", type=_finite, metavar="DEG",
                   help="tilt each light's direction by up to DEG degrees (default 0)")
    g.add_argument("--light-intensity", type=_pair, metavar="LO,HI",
                   help="multiply each light's intensity by U(LO,HI) (default 1,1)")
    g.add_argument("--background-jitter", type=_count, metavar="N",
                   help="add U{-N..N} to each background channel (default 0)")
    g.add_argument("--offset", type=_finite, metavar="PX",
                   help="move the sphere's image centre by U(-PX,PX) pixels in u and v (default 0)")
    g.add_argument("--scale", type=_finite, metavar="FRAC",
                   help="multiply the focal length (sphere size) by U(1-FRAC,1+FRAC) (default 0)")
    g.add_argument("--exposure", type=_pair, metavar="LO,HI", help="image gain U(LO,HI) (default 1,1)")
    g.add_argument("--gamma", type=_pair, metavar="LO,HI", help="gamma U(LO,HI), out = in^(1/gamma) (default 1,1)")
    g.add_argument("--blur", type=_finite, metavar="SIGMA", help="Gaussian blur, sigma U(0,SIGMA) px (default 0)")
    g.add_argument("--noise", type=_finite, metavar="SIGMA",
                   help="Gaussian sensor noise, sigma U(0,SIGMA) 8-bit levels (default 0)")


def _background(args):
    return args.background if args.background is not None else (64, 64, 70)


def _scene(args):
    """The parsed --scene file (None without one); refuses the options a scene replaces."""
    if args.scene is None:
        return None
    clash = [f"--{name.replace('_', '-')}" for name in ("background", "lights") if getattr(args, name) is not None]
    clash += [f"--{attr.replace('_', '-')}" for attr in _RZ_FLAGS.values() if getattr(args, attr, None) is not None]
    if getattr(args, "randomize", False):
        clash.append("--randomize")
    if getattr(args, "multisamples", 0):
        clash.append("--multisamples")
    if clash:
        raise UsageError(f"--scene {args.scene} describes the background, lights and randomisation; "
                         f"drop {', '.join(clash)} (or edit the scene file)")
    from sim.scene import load_scene
    camera = load_camera(args.camera) if args.camera else None
    return load_scene(args.scene, camera_override=camera)


def _randomization(args):
    from sim.randomize import Randomization, check, with_preset
    given = {field: getattr(args, attr) for field, attr in _RZ_FLAGS.items() if getattr(args, attr) is not None}
    rz = Randomization(**given)
    if args.randomize:
        rz = with_preset(rz, given)
    try:
        return check(rz)
    except ValueError as e:
        raise UsageError(str(e)) from None


# ---- render ----------------------------------------------------------------

def cmd_render(args):
    from sim.frames import encode_png, write_atomic
    from sim.render import Renderer, DEFAULT_LIGHTS
    scene = _scene(args)
    camera = load_camera(args.camera)
    lights = _load_lights(args.lights) or DEFAULT_LIGHTS
    if not args.out.lower().endswith(".png"):
        raise UsageError(f"--out {args.out}: the output must be a .png file")
    out_dir = os.path.dirname(os.path.abspath(args.out))
    if not os.path.isdir(out_dir):
        raise UsageError(f"--out {args.out}: folder {out_dir} does not exist")
    if args.truth is not None and scene is None:
        raise UsageError("--truth needs --scene (the plain frame's circle is the camera file's)")
    if scene is not None:
        import json
        import numpy as np
        from sim.scene_render import SceneRenderer
        img, params = SceneRenderer(args.texture, scene).frame(tuple(args.pose), np.random.default_rng([args.seed]))
        write_atomic(args.out, encode_png(img))
        if args.truth is not None:
            line = {"file": os.path.basename(args.out), "pose": list(args.pose), "circle": params["circle"],
                    "scene": {k: v for k, v in params.items() if k != "circle"}}
            write_atomic(args.truth, (json.dumps(line) + "\n").encode())
        return 0
    renderer = Renderer(args.texture, camera, lights=lights, background=_background(args),
                        multisamples=args.multisamples)
    img = renderer.render(tuple(args.pose))
    write_atomic(args.out, encode_png(img))
    return 0


# ---- dataset ---------------------------------------------------------------

def cmd_dataset(args, argv):
    from sim.dataset import AXES, DatasetConfig, build
    scene = _scene(args)
    camera = scene.camera if scene is not None else load_camera(args.camera)
    ranges = {a: getattr(args, f"range_{a}") or tuple(args.range) for a in AXES}
    counts = {"train": args.train, "val": args.val, "test": args.test, "test_offgrid": args.offgrid_test}
    cfg = DatasetConfig(texture=args.texture, camera=camera, ranges=ranges, step=args.step, counts=counts,
                        sampling=args.sampling, seed=args.seed, background=_background(args),
                        lights=_load_lights(args.lights), randomization=_randomization(args), scene=scene)
    log = (lambda *a: None) if args.quiet else (lambda *a: print(*a, file=sys.stderr))
    if args.ray_address and args.engine != "ray":
        raise UsageError("--ray-address needs --engine ray")
    host, _, port = (args.ray_address or "h:0").rpartition(":")
    if not host or not port.isdigit():
        raise UsageError(f"--ray-address {args.ray_address}: expected HOST:PORT, the head's address "
                         f"(ray start --head prints it)")
    record = build(cfg, args.out, workers=args.workers, progress=not args.quiet,
                   command=shlex.join(["sim"] + list(argv)), log=log, engine=args.engine,
                   ray_address=args.ray_address)
    run = record["last_run"]
    log(f"dataset complete in {args.out}: " +
        ", ".join(f"{k} {v}" for k, v in record["counts"].items()) +
        (f"; rendered {run['rendered']} frames at {run['frames_per_s']} frames/s on {run['workers']} "
         f"{'Ray CPUs' if args.engine == 'ray' else 'workers'}"
         if run["rendered"] else "; nothing left to render"))
    return 0


# ---- vcam ------------------------------------------------------------------

def cmd_vcam(args):
    from sim import vcam
    from sim.render import DEFAULT_LIGHTS
    scene = _scene(args)
    camera = scene.camera if scene is not None else load_camera(args.camera)
    sources = [args.stage_state is not None, args.pose is not None, args.pose_file is not None]
    if sum(sources) != 1:
        raise UsageError("give exactly one pose source: --stage-state PATH, --pose X Y Z or --pose-file FILE")
    if args.stage_state:
        source = vcam.StageStateSource(args.stage_state)
    elif args.pose is not None:
        source = vcam.FixedPoseSource(tuple(args.pose))
    else:
        source = vcam.PoseFileSource(args.pose_file)
    server = vcam.FrameServer(args.socket, texture=args.texture, camera=camera,
                              lights=_load_lights(args.lights) or DEFAULT_LIGHTS, background=_background(args),
                              source=source, randomization=_randomization(args), seed=args.seed,
                              frame_log=args.frame_log, scene=scene)
    return server.serve_forever()


# ---- parser ----------------------------------------------------------------

def get_args_parser():
    parser = argparse.ArgumentParser(prog="sim", description="Render the textured sphere (docs/sim.md).")
    sub = parser.add_subparsers(dest="command", required=True, metavar="{render,dataset,vcam}")

    p = sub.add_parser("render", help="one frame at one pose",
                       description="Render one frame of the textured sphere at one pose and write it "
                                   "atomically as PNG.",
                       formatter_class=_Help)
    _add_scene_args(p)
    p.add_argument("--pose", type=_finite, nargs=3, required=True, metavar=("X", "Y", "Z"),
                   help="pose in degrees, R = Rz(z) Ry(y) Rx(x) (required)")
    p.add_argument("--out", required=True, metavar="PNG", help="output PNG (required)")
    p.add_argument("--multisamples", type=_count, default=0, metavar="N",
                   help="MSAA samples for a smoother silhouette (slower)")
    p.add_argument("--seed", type=int, default=0, help="with --scene: the seed of the scene's draw")
    p.add_argument("--truth", metavar="JSON",
                   help="with --scene: also write the frame's truth line (pose, circle, the scene's draw)")

    p = sub.add_parser("dataset", help="a labelled dataset (P1 protocol by default)",
                       description="Render a dataset <split>/<x>_<y>_<z>.png (and <split>/truth.jsonl) with a record dataset.json. "
                                   "Resumable: rerun the same command to finish a killed run.",
                       formatter_class=_Help)
    _add_scene_args(p)
    p.add_argument("--out", required=True, metavar="DIR", help="dataset folder (required)")
    p.add_argument("--seed", type=int, default=0, help="seed of the pose draw and the randomisation")
    p.add_argument("--step", type=_finite, default=3.0, metavar="DEG", help="grid step in degrees")
    p.add_argument("--range", type=_pair, default=(-30.0, 30.0), metavar="LO,HI",
                   help="range of every axis in degrees")
    for a in "xyz":
        p.add_argument(f"--range-{a}", type=_pair, metavar="LO,HI", help=f"range of {a}, overriding --range")
    p.add_argument("--train", type=_count, default=1600, metavar="N", help="poses in train/")
    p.add_argument("--val", type=_count, default=597, metavar="N", help="poses in val/")
    p.add_argument("--test", type=_count, default=100, metavar="N", help="poses in test/")
    p.add_argument("--offgrid-test", type=_count, default=100, metavar="N",
                   help="poses in test_offgrid/, uniform in the ranges and off the grid")
    p.add_argument("--sampling", choices=("grid", "continuous"), default="grid",
                   help="train/val/test poses on the grid (without repetition) or uniform in the ranges "
                        "(any count, 3-decimal labels)")
    p.add_argument("--workers", type=_count, default=0, metavar="N",
                   help="worker processes, one renderer each (0: every core); with --engine ray: the CPUs "
                        "of the local Ray instance, or on a cluster at most N tasks at a time (0: all its CPUs)")
    p.add_argument("--engine", choices=("local", "ray"), default="local",
                   help="local: worker processes on this machine; ray: Ray tasks on a cluster "
                        "(docs/cluster.md), the same frames byte for byte")
    p.add_argument("--ray-address", metavar="ADDR",
                   help="with --engine ray: the cluster to join, e.g. 10.0.0.1:6379 (default: RAY_ADDRESS, "
                        "else a local Ray instance with --workers CPUs, started and stopped by this run)")
    p.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    _add_randomization_args(p)

    p = sub.add_parser("vcam", help="virtual camera: a frame server on a Unix socket",
                       description="Serve frames on a Unix stream socket (docs/interfaces.md, 'Frame sources'): "
                                   "each 'grab\\n' gets 'FRAME <n>\\n' + PNG bytes of the sphere at the stage's "
                                   "true angles, or 'ERROR <message>\\n'. Prints 'VCAM <socket>' when ready; "
                                   "SIGTERM/SIGINT stop it and remove the socket.",
                       formatter_class=_Help)
    _add_scene_args(p)
    p.add_argument("--socket", required=True, metavar="PATH", help="Unix socket to serve on (required)")
    p.add_argument("--stage-state", metavar="PATH",
                   help="stagesim state socket: each frame renders the angles it reports")
    p.add_argument("--pose", type=_finite, nargs=3, metavar=("X", "Y", "Z"), help="serve one fixed pose")
    p.add_argument("--pose-file", metavar="FILE",
                   help="serve the poses of a text file, one 'x y z' line each, in turn (cycling)")
    p.add_argument("--seed", type=int, default=0, help="seed of the per-frame randomisation")
    p.add_argument("--frame-log", metavar="FILE",
                   help="append one JSON line per frame served: its index and the angles it shows "
                        "(how a test knows where the stage really was)")
    _add_randomization_args(p)
    return parser


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    args = get_args_parser().parse_args(argv)
    from sim.dataset import DatasetError
    from sim.engine_ray import EngineError
    from sim.render import TextureError
    try:
        if args.command == "render":
            return cmd_render(args)
        if args.command == "dataset":
            return cmd_dataset(args, argv)
        return cmd_vcam(args)
    except (CameraError, TextureError, DatasetError, UsageError, ValueError) as e:
        print(f"sim {args.command}: error: {e}", file=sys.stderr)
        return 2
    except EngineError as e:    # the cluster, not the arguments: frames written so far stay, rerun to resume
        print(f"sim {args.command}: error: {e}; rerun the same command to resume", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"sim {args.command}: interrupted" +
              ("; rerun the same command to resume" if args.command == "dataset" else ""), file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
