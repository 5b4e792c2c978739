"""A folder of frames of one family: <x>_<y>_<z>.png plus truth.jsonl (the shared contract).

truth.jsonl has one JSON line per frame, in index order:
{"file": "x_y_z.png", "pose": [x, y, z], "circle": [cx, cy, r], "scene": {...}}
(frames a runtime must refuse add "expect": "refuse"; without a sphere the circle is null)
with the circle in continuous pixels of the undistorted image and the scene
the dict that `render.render` drew the frame from (plus "hidden_rim", the
share of the outline a mount hides). params.json records what made the
folder (the texture by its content, so the same image reached by another
path is the same); a folder with the same params.json is complete and is
reused. A folder is the tool's own once its params.json is there: only then
are its frames replaced, and PNG files in a folder without one are never
deleted.
"""
import hashlib
import json
import os
from concurrent.futures import ProcessPoolExecutor

import cv2

from . import families, render


def angle_text(v):
    """A name's angle: optional '-', integer part, optional '.' and 1 to 3 digits (docs/conventions.md)."""
    text = f"{v:.3f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def frame_name(pose):
    return "_".join(angle_text(v) for v in pose) + ".png"


def write_atomic(path, data):
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "wb") as f:
        f.write(data)
    os.replace(tmp, path)


def texture_record(path):
    """The texture as params.json records it: its file, and its SHA-256 that decides sameness."""
    with open(path, "rb") as f:
        digest = hashlib.sha256(f.read()).hexdigest()
    return {"file": os.path.abspath(path), "sha256": digest}


def _comparable(params):
    """params with the texture reduced to its SHA-256; a params.json of before the texture
    carried one names a file, whose content is hashed if it is still there."""
    out = dict(params)
    tex = out.get("texture")
    if isinstance(tex, dict):
        out["texture"] = tex.get("sha256")
    elif isinstance(tex, str) and os.path.isfile(tex):
        out["texture"] = texture_record(tex)["sha256"]
    return out


class FolderError(RuntimeError):
    """A frame folder this tool will not fill: someone else's files, or a seed that draws a pose
    twice. The message says which folder and what to do; the commands print it and exit."""


def reuse_or_clear(outdir, params):
    """True when `outdir` holds a complete set made with `params` (params.json the same, truth.jsonl
    there). Otherwise make `outdir` the tool's own for a new set and return False: the earlier set's
    frames and records go, and params.json is written first, so a killed run leaves a folder this
    tool may clear again. A folder with PNG files and no params.json is someone else's: FolderError."""
    os.makedirs(outdir, exist_ok=True)
    ppath, tpath = os.path.join(outdir, "params.json"), os.path.join(outdir, "truth.jsonl")
    old = None
    if os.path.exists(ppath):
        try:
            with open(ppath, encoding="utf-8") as f:
                old = json.load(f)
        except (OSError, ValueError):
            old = {}  # ours, but unreadable: made again
        if os.path.exists(tpath) and _comparable(old) == _comparable(params):
            return True
    pngs = sorted(n for n in os.listdir(outdir) if n.lower().endswith(".png"))
    if old is None and pngs:
        raise FolderError(f"{outdir}: holds {len(pngs)} PNG file(s) (e.g. {pngs[0]}) and no params.json "
                           f"of this tool; not replacing them: choose an empty or new folder")
    if os.path.exists(tpath):
        os.remove(tpath)
    write_atomic(ppath, (json.dumps(dict(params, complete=False), indent=1) + "\n").encode())
    for name in pngs:
        os.remove(os.path.join(outdir, name))
    return False


def finish_folder(outdir, params, truths):
    """truth.jsonl, then params.json: from then on the folder is complete and reused."""
    lines = "".join(json.dumps(t) + "\n" for t in truths)
    write_atomic(os.path.join(outdir, "truth.jsonl"), lines.encode())
    write_atomic(os.path.join(outdir, "params.json"), (json.dumps(params, indent=1) + "\n").encode())


def encode_png(img):
    """PNG bytes of an RGB uint8 frame."""
    ok, png = cv2.imencode(".png", cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return png.tobytes()


def truth_line(scene, cam):
    """The truth.jsonl record of a frame drawn from `scene` (adds "hidden_rim" to the scene)."""
    scene["hidden_rim"] = render.hidden_rim_fraction(scene, cam) if scene.get("mount") else 0.0
    circle = [round(c, 4) for c in render.circle(scene, cam)] if scene.get("sphere", True) else None
    truth = {"file": frame_name(scene["pose"]), "pose": scene["pose"], "circle": circle, "scene": scene}
    if scene.get("expect"):
        truth["expect"] = scene["expect"]
    return truth


def make_frame(family, seed, index, cam, tex, supersample=4):
    """(file name, PNG bytes, truth dict) of one frame."""
    scene = families.draw_scene(family, seed, index, cam)
    png = encode_png(render.render(scene, cam, tex, supersample))
    truth = truth_line(scene, cam)
    return truth["file"], png, truth


_WORKER = {}


def _init(cam, texture_path):
    _WORKER["cam"] = cam
    _WORKER["tex"] = render.load_texture(texture_path)


def _job(args):
    family, seed, index, outdir, supersample = args
    name, png, truth = make_frame(family, seed, index, _WORKER["cam"], _WORKER["tex"], supersample)
    write_atomic(os.path.join(outdir, name), png)
    return index, truth


def write_family(outdir, family, n, seed, cam, texture_path, jobs=1, supersample=4, progress=None):
    """Render frames 0..n-1 of `family` into `outdir` and write truth.jsonl; reuse a complete folder
    made with the same parameters. `progress(k)` is called as frames finish."""
    params = {"family": family, "n": n, "seed": seed, "camera": cam.to_dict(),
              "texture": texture_record(texture_path), "supersample": supersample, "version": 1}
    tpath = os.path.join(outdir, "truth.jsonl")
    if reuse_or_clear(outdir, params):
        if progress:
            progress(n)
        return tpath
    truths = [None] * n
    work = [(family, seed, i, outdir, supersample) for i in range(n)]
    if jobs > 1:
        with ProcessPoolExecutor(jobs, initializer=_init, initargs=(cam, texture_path)) as ex:
            for i, truth in ex.map(_job, work, chunksize=2):
                truths[i] = truth
                if progress:
                    progress(1)
    else:
        _init(cam, texture_path)
        for w in work:
            i, truth = _job(w)
            truths[i] = truth
            if progress:
                progress(1)
    names = [t["file"] for t in truths]
    if len(set(names)) != len(names):
        raise FolderError(f"{outdir}: two frames drew the same pose; use another seed")
    finish_folder(outdir, params, truths)
    return tpath
