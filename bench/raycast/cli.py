"""The inputs every command of the ray-caster shares (`python bench/raycast`,
bench/sensor_stages.py): the texture, the camera file and the supersampling, as
arguments, and the texture's and camera file's checks."""
import os
import sys

from . import camera

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def add_scene_arguments(ap):
    """--texture, --camera and --supersample on the argparse parser ap."""
    ap.add_argument("--texture", default=os.path.join(ROOT, "build", "textures", "Texture_3_color.png"),
                    help="equirectangular texture (textures generate)")
    ap.add_argument("--camera", default=None, help="camera file (default: the reference camera)")
    ap.add_argument("--supersample", type=int, default=4, help="rays per pixel per side on the sphere and edges")


def load_camera(args, prog):
    """The camera of args.camera, once args.texture is known to exist; else exits with the error,
    prefixed by prog."""
    if not os.path.isfile(args.texture):
        sys.exit(f"{prog}: {args.texture}: no such texture (make textures writes build/textures/)")
    try:
        return camera.load_camera(args.camera)
    except camera.CameraFileError as e:
        sys.exit(f"{prog}: {e}")
