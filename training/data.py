"""Pose datasets from file names only, preprocessed once and cached.

A split folder holds `<x>_<y>_<z>.png` frames (sim.names is the only parser);
other PNG names are an error that names the file, other file types are
ignored. The preprocessing up to the crop (training/preprocess.py, the
algorithm the parameters name) runs once per frame, with the frame's own
camera calibration when the split has a truth.jsonl of rig scenes; the uint8
crops are cached in the folder as `.spherepose-cache-<P>-<F>.npz`: P hashes
the preprocessing parameters, F every frame's name, size and mtime (and the
truth record's), so a change to either rebuilds it; caches of
other parameter sets are kept, and concurrent runs never clash.
Step 8 (normalise) runs on batches in torch, with the same float32 arithmetic,
after optional augmentation of the uint8 crops.
"""
import hashlib
import json
import os
import sys
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from sim.names import parse_name

from . import preprocess as pp
from .refine import LUMA

CACHE_PREFIX = ".spherepose-cache-"


class DatasetError(ValueError):
    """A split folder that cannot be used; the message names the folder or file."""


def list_frames(root):
    """Sorted PNG paths and their [N, 3] labels (degrees) from a split folder."""
    root = Path(root)
    if not root.is_dir():
        raise DatasetError(f"{root}: not a folder")
    paths = sorted(p for p in root.iterdir() if p.suffix.lower() == ".png" and p.is_file())
    if not paths:
        raise DatasetError(f"{root}: empty split, no <x>_<y>_<z>.png frames")
    labels = np.array([parse_name(p) for p in paths], dtype=np.float64)
    return paths, labels


def label_range_problems(names, labels, ranges):
    """'name (x 400 outside -30..30)' for every frame whose label [N, 3] (degrees) lies outside
    ranges {'x': [lo, hi], 'y': ..., 'z': ...}."""
    lo = np.array([ranges[a][0] for a in "xyz"], np.float64)
    hi = np.array([ranges[a][1] for a in "xyz"], np.float64)
    lab = np.asarray(labels, np.float64)
    bad = (lab < lo - 1e-6) | (lab > hi + 1e-6)
    out = []
    for i in np.nonzero(bad.any(1))[0]:
        parts = [f"{a} {lab[i, k]:g} outside {lo[k]:g}..{hi[k]:g}" for k, a in enumerate("xyz") if bad[i, k]]
        out.append(f"{names[i]} ({', '.join(parts)})")
    return out


def check_label_ranges(ds, ranges, strict=False, warn=None):
    """Name the frames of ds (a PoseSet) labelled outside the model's ranges: a warning on stderr, or
    with strict a DatasetError. Such a label (a typo like 400_0_0.png, a frame of another protocol)
    asks the network for a pose it is not made to give and skews every metric; quietly training on it
    is how a mistake in the data goes unseen. Returns the problems (empty when all is well)."""
    problems = label_range_problems(ds.names, ds.labels.numpy(), ranges)
    if not problems:
        return problems
    shown = "; ".join(problems[:10]) + (f"; and {len(problems) - 10} more" if len(problems) > 10 else "")
    span = ", ".join(f"{a} {ranges[a][0]:g}..{ranges[a][1]:g}" for a in "xyz")
    text = (f"{ds.root}: {len(problems)} of {len(ds)} frames are labelled outside the model's ranges "
            f"({span} degrees): {shown}")
    if strict:
        raise DatasetError(text)
    if warn is None:
        warn = lambda msg: print(msg, file=sys.stderr, flush=True)
    warn(f"posetrain: warning: {text}; training on them anyway (--strict refuses them)")
    return problems


def _cache_key(paths, params):
    """'<params hash>-<files hash>': one cache per parameter set, rebuilt when the frames change."""
    hp = hashlib.sha1(json.dumps(params, sort_keys=True).encode()).hexdigest()[:8]
    h = hashlib.sha1()
    for p in paths:
        st = p.stat()
        h.update(f"{p.name}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
    truth = paths[0].parent / "truth.jsonl" if paths else None
    if truth is not None and truth.exists():
        h.update(f"truth.jsonl\0{truth.stat().st_mtime_ns}\n".encode())
    return f"{hp}-{h.hexdigest()[:12]}"


def frame_cameras(root):
    """{file name: camera dict} from a split's truth.jsonl (sim dataset --scene writes the camera
    each frame was drawn with), so a frame is undistorted and its radius expected as a calibrated
    user's would be. {} when the split has no such record (plain renders: the reference camera)."""
    path = Path(root) / "truth.jsonl"
    if not path.exists():
        return {}
    from sim.camera import from_truth
    out = {}
    with open(path) as f:
        for n, line in enumerate(f, 1):
            try:
                rec = json.loads(line)
                cam = (rec.get("scene") or {}).get("camera")
                if cam is None:
                    continue
                out[rec["file"]] = from_truth(cam)
            except (ValueError, KeyError, TypeError) as e:
                raise DatasetError(f"{path}:{n}: not a truth record ({e})") from None
    return out


def sized_camera(camera, frame, default=None):
    """A frame's camera from its truth record (a frame_cameras value) with the width and height of
    the frame as read, else `default` (a camera file's, or None: the runtime's search)."""
    return default if camera is None else dict(camera, width=frame.shape[1], height=frame.shape[0])


def frame_camera(folders, path, frame, default=None):
    """The camera of the frame at `path` (`frame`, its image as read): its folder's truth.jsonl
    record, read once per folder into the dict `folders`, sized to the frame (sized_camera); else
    `default`. For tools that take frames from many folders (python -m training.refine)."""
    path = Path(path)
    if path.parent not in folders:
        folders[path.parent] = frame_cameras(path.parent)
    return sized_camera(folders[path.parent].get(path.name), frame, default)


def _crop_file(path, params, camera=None):
    """The frame's uint8 BGR crop, or a str saying why the localisation refused it."""
    frame = pp.cv2.imread(str(path), pp.cv2.IMREAD_UNCHANGED)
    if frame is None:
        raise DatasetError(f"{path}: cannot decode image (missing, corrupt or not an image)")
    if frame.dtype != np.uint8:
        raise DatasetError(f"{path}: expected 8-bit pixels, got {frame.dtype}")
    camera = sized_camera(camera, frame)
    try:
        return pp.crop_frame(frame, params, camera)[0]
    except pp.NoSphere as e:
        return f"{path.name}: {e}"


def _crop_job(job, params):
    return _crop_file(job[0], params, job[1])


def load_crops(root, params, cache=True, progress=True, workers=1):
    """(crops uint8 [N, S, S, 3] RGB, labels [N, 3] float64, names) for a split folder.
    Frames the localisation refuses (no sphere, or not one whole sphere, found) are left out
    with a warning that names them: a training set is drawn wide, and a frame the runtime
    would refuse teaches nothing. workers: preprocessing processes (0 = every core)."""
    paths, labels = list_frames(root)
    root = Path(root)
    key = _cache_key(paths, params)
    cpath = root / f"{CACHE_PREFIX}{key}.npz"
    names = [p.name for p in paths]
    if cache and cpath.exists():
        try:
            with np.load(cpath) as z:
                crops, kept = z["crops"], z["kept"]
            if len(kept) == len(paths) and len(crops) == int(kept.sum()):
                return crops, labels[kept], [n for n, k in zip(names, kept) if k]
        except Exception:
            pass  # unreadable or older cache: rebuild it
    cams = frame_cameras(root)
    jobs = [(p, cams.get(p.name)) for p in paths]
    workers = max(1, min(workers or (os.cpu_count() or 1), len(paths) // 64 or 1))
    if workers > 1:
        import multiprocessing
        import functools
        ctx = multiprocessing.get_context("fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn")
        pool = ctx.Pool(workers)
        it = pool.imap(functools.partial(_crop_job, params=params), jobs, chunksize=16)
    else:
        pool = None
        it = (_crop_job(j, params) for j in jobs)
    if progress:
        from tqdm import tqdm
        it = tqdm(it, total=len(paths), desc=f"preprocess {root.name}", unit="frame", leave=False)
    try:
        results = list(it)
    finally:
        if pool is not None:
            pool.terminate()
    refused = [r for r in results if isinstance(r, str)]
    kept = np.array([not isinstance(r, str) for r in results], dtype=bool)
    if not kept.any():
        raise DatasetError(f"{root}: the sphere was found in none of its {len(paths)} frames "
                           f"(first: {refused[0]})")
    if refused:
        shown = "; ".join(refused[:5]) + (f"; and {len(refused) - 5} more" if len(refused) > 5 else "")
        print(f"posetrain: warning: {root}: {len(refused)} of {len(paths)} frames left out, "
              f"the localisation refused them: {shown}", file=sys.stderr, flush=True)
    crops = np.stack([r[:, :, ::-1] for r in results if not isinstance(r, str)])  # BGR -> RGB
    if cache:
        for old in root.glob(f"{CACHE_PREFIX}{key.split('-')[0]}-*.npz"):
            if old != cpath:  # stale: same parameters, other frames
                old.unlink(missing_ok=True)
        tmp = root / f".spherepose-tmp-{os.getpid()}.npz"
        np.savez(tmp, crops=crops, kept=kept)
        os.replace(tmp, cpath)  # atomic: a killed or concurrent run never leaves half a cache
    return crops, labels[kept], [n for n, k in zip(names, kept) if k]


class PoseSet:
    """An in-memory split: uint8 crops [N, 3, S, S] (RGB) and labels [N, 3] (float32, degrees)."""

    def __init__(self, root, params, cache=True, progress=True, workers=1):
        crops, labels, names = load_crops(root, params, cache, progress, workers)
        self.root, self.params, self.names = Path(root), params, names
        self.images = torch.from_numpy(np.ascontiguousarray(crops.transpose(0, 3, 1, 2)))
        self.labels = torch.from_numpy(labels.astype(np.float32))

    def __len__(self):
        return len(self.labels)

    def batches(self, batch_size, shuffle=False, generator=None, drop_last=False):
        """Yield (uint8 images, labels) batches."""
        n = len(self)
        order = torch.randperm(n, generator=generator) if shuffle else torch.arange(n)
        stop = n - n % batch_size if drop_last and n >= batch_size else n
        for i in range(0, stop, batch_size):
            idx = order[i:i + batch_size]
            yield self.images[idx], self.labels[idx]


def normalise(images_u8_or_float, params):
    """Step 8 in torch: uint8 RGB (or float in [0, 1]) [N, 3, S, S] -> normalised float32."""
    x = images_u8_or_float
    if x.dtype == torch.uint8:
        x = x.to(torch.float32) / 255.0
    mean = torch.tensor(params["mean"], dtype=torch.float32, device=x.device).view(1, 3, 1, 1)
    std = torch.tensor(params["std"], dtype=torch.float32, device=x.device).view(1, 3, 1, 1)
    return (x - mean) / std


# ---------------------------------------------------------------- augmentation

def _gaussian_blur(x, sigma):
    """Per-sample Gaussian blur, sigma [N] in pixels (0 = none), 5-tap separable kernel."""
    t = torch.arange(-2, 3, dtype=x.dtype, device=x.device).view(1, 5)
    s = sigma.clamp(min=1e-3).view(-1, 1)
    k = torch.exp(-0.5 * (t / s) ** 2)
    k = k / k.sum(1, keepdim=True)  # [N, 5]
    n, c, h, w = x.shape
    y = x.reshape(1, n * c, h, w)
    kh = k.repeat_interleave(c, 0).view(n * c, 1, 1, 5)
    y = F.conv2d(F.pad(y, (2, 2, 0, 0), mode="replicate"), kh, groups=n * c)
    y = F.conv2d(F.pad(y, (0, 0, 2, 2), mode="replicate"), kh.transpose(2, 3), groups=n * c)
    return y.view(n, c, h, w)


def photometric(x, g, strength=1.0):
    """Random light: brightness, contrast, per-channel gain, gamma, blur, noise.
    x float [N, 3, S, S] in [0, 1]; g a torch.Generator; returns the same shape in [0, 1]."""
    n = x.shape[0]
    u = lambda lo, hi, *shape: lo + (hi - lo) * torch.rand(n, *shape, generator=g)
    s = strength
    x = x * u(1 - 0.3 * s, 1 + 0.3 * s, 1, 1, 1) * u(1 - 0.08 * s, 1 + 0.08 * s, 3, 1, 1)
    m = x.mean((1, 2, 3), keepdim=True)
    x = ((x - m) * u(1 - 0.3 * s, 1 + 0.3 * s, 1, 1, 1) + m).clamp(0, 1)
    x = x ** torch.exp(u(-0.25 * s, 0.25 * s, 1, 1, 1))
    blur = torch.where(torch.rand(n, generator=g) < 0.5, u(0.3, 0.3 + 1.0 * s), torch.zeros(n))
    x = torch.where((blur > 0).view(-1, 1, 1, 1), _gaussian_blur(x, blur), x)
    x = x + torch.randn(x.shape, generator=g) * u(0, 0.03 * s, 1, 1, 1)
    return x.clamp(0, 1)


def gray(x, g, p):
    """With probability p per sample, the crop as a mono camera sees it: its luma in all
    three channels (refine.LUMA, OpenCV's BGR2GRAY weights, the ones refinement renders a
    gray frame's texture with), as preprocess.py widens a one-channel frame.
    x float RGB [N, 3, S, S] in [0, 1]."""
    n = x.shape[0]
    w = torch.tensor(LUMA[::-1], dtype=x.dtype, device=x.device).view(1, 3, 1, 1)  # B, G, R -> R, G, B
    y = (x * w).sum(1, keepdim=True).expand_as(x)
    pick = (torch.rand(n, generator=g) < p).view(-1, 1, 1, 1).to(x.device)
    return torch.where(pick, y, x)


def geometric(x, g, shift=0.04, scale=0.04):
    """Small random crop jitter (translation, scale), as an imperfect sphere detection
    would give; no in-plane rotation (that would change the Z angle)."""
    n = x.shape[0]
    u = lambda lo, hi: lo + (hi - lo) * torch.rand(n, generator=g)
    sc = u(1 - scale, 1 + scale)
    theta = torch.zeros(n, 2, 3)
    theta[:, 0, 0] = sc
    theta[:, 1, 1] = sc
    theta[:, 0, 2] = u(-2 * shift, 2 * shift)
    theta[:, 1, 2] = u(-2 * shift, 2 * shift)
    grid = F.affine_grid(theta, list(x.shape), align_corners=False)
    return F.grid_sample(x, grid, mode="bilinear", padding_mode="border", align_corners=False)


def prepare_batch(images_u8, params, augment=None, g=None):
    """uint8 batch -> normalised float32 network input, optionally augmented.
    augment: None or a dict {'photometric': strength (0 = off), 'geometric': bool,
    'gray': probability of a mono-camera crop (0 = off)}."""
    if not augment or not (augment.get("photometric") or augment.get("geometric") or augment.get("gray")):
        return normalise(images_u8, params)
    x = images_u8.to(torch.float32) / 255.0
    if augment.get("geometric"):
        x = geometric(x, g)
    if augment.get("photometric"):
        x = photometric(x, g, augment["photometric"])
    if augment.get("gray"):
        x = gray(x, g, augment["gray"])  # after the light: a mono sensor sees the lit scene
    return normalise(x, params)
