"""python bench/raycast --family F --n N --seed S --out DIR: frames of one family and their truth.jsonl."""
import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from raycast import cli, families, frames  # noqa: E402


def get_args_parser():
    ap = argparse.ArgumentParser(
        prog="python bench/raycast",
        description="Render evaluation frames of the textured sphere with the independent ray-caster: "
                    "<x>_<y>_<z>.png and truth.jsonl (pose, circle, scene) in --out.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--family", required=True, choices=families.FAMILIES + families.EXTRA_FAMILIES,
                    help="scene family")
    ap.add_argument("--n", type=int, default=100, help="frames")
    ap.add_argument("--seed", type=int, default=0, help="seed (each family draws its own frames from it)")
    ap.add_argument("--out", required=True, help="output folder")
    cli.add_scene_arguments(ap)
    ap.add_argument("--jobs", type=int, default=1, help="frames rendered at once")
    return ap


def main(argv=None):
    args = get_args_parser().parse_args(argv)
    if args.n < 1 or args.supersample < 1 or args.jobs < 1:
        sys.exit("raycast: --n, --supersample and --jobs must be at least 1")
    cam = cli.load_camera(args, "raycast")
    t0 = time.time()
    try:
        path = frames.write_family(args.out, args.family, args.n, args.seed, cam, args.texture,
                                   jobs=args.jobs, supersample=args.supersample)
    except frames.FolderError as e:
        sys.exit(f"raycast: {e}")
    print(f"{path}: {args.n} frames of {args.family} in {time.time() - t0:.1f} s")


if __name__ == "__main__":
    main()
