"""The labelled dataset: poses, splits, rendering on every core, resumable, byte-for-byte reproducible.

Layout of a dataset folder:

    OUT/dataset.json                 the record (command, seed, texture, camera, settings, counts)
    OUT/<split>/<x>_<y>_<z>.png      frames; the label is the file name (sim/names.py)
    OUT/<split>/truth.jsonl          one line per frame: file, pose, the sphere's circle (and a scene's draw)

Splits: train, val, test (grid poses, or continuous with --sampling continuous)
and test_offgrid (poses drawn uniformly in the ranges, never on the grid).

Poses. Grid: every axis takes lo, lo + step, ..., hi; `train + val + test`
distinct grid poses are drawn without repetition with generator
default_rng([seed, 0]) and dealt to the splits in that order. Continuous:
poses uniform in the ranges, rounded to the file names' 3 decimals, no two
alike, from the same generator. Off-grid test: uniform, rounded, not on the
grid and not in another split, from default_rng([seed, 1]).

Frames. Pose number i (train first, then val, test, test_offgrid) draws its
randomisation from default_rng([seed, 2, i]), so a frame depends only on the
settings, the seed and i: any number of workers, any order, any interruption
gives the same bytes.
"""
import hashlib
import json
import multiprocessing
import os
import shlex
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from sim import names
from sim.camera import Camera
from sim.frames import (PNG_FILTER, PNG_LEVEL, commit_temporary, encode_png, frame_problem,
                        remove_stale_temporaries, write_atomic, write_temporary)
from sim.randomize import Randomization

SPLITS = ("train", "val", "test", "test_offgrid")
RECORD = "dataset.json"
TRUTH = "truth.jsonl"
FORMAT = "spherepose-dataset-1"
AXES = ("x", "y", "z")
COMMIT_THREADS = 4     # the parent's threads that fsync and rename finished frames (fsyncs overlap)


class DatasetError(ValueError):
    """Bad dataset arguments or a folder that cannot be resumed; the message says which and why."""


@dataclass
class DatasetConfig:
    """Everything that decides a dataset's content (the record's `settings`)."""
    texture: str
    camera: Camera = field(default_factory=Camera)
    ranges: dict = field(default_factory=lambda: {a: (-30.0, 30.0) for a in AXES})
    step: float = 3.0
    counts: dict = field(default_factory=lambda: {"train": 1600, "val": 597, "test": 100, "test_offgrid": 100})
    sampling: str = "grid"
    seed: int = 0
    background: tuple = (64, 64, 70)
    lights: tuple = None  # None: sim.render.DEFAULT_LIGHTS
    randomization: Randomization = field(default_factory=Randomization)
    scene: object = None  # a sim.scene.Scene: replaces camera, background, lights and randomisation


def sha256_file(path):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def grid_values(lo, hi, step, axis="x"):
    """Grid values lo, lo + step, ..., hi of one axis (hi must be on the grid)."""
    if step <= 0:
        raise DatasetError(f"step must be > 0, got {step}")
    if hi < lo:
        raise DatasetError(f"range of {axis}: low {lo} is above high {hi}")
    n = (hi - lo) / step
    if abs(n - round(n)) > 1e-6:
        raise DatasetError(f"range of {axis} [{lo}, {hi}] is not a whole number of steps of {step}")
    return [names.quantize(lo + k * step, 0, 0)[0] for k in range(int(round(n)) + 1)]


def _uniform_poses(rng, ranges, count, exclude, on_grid=None):
    """`count` distinct uniform poses (rounded to 3 decimals) not in `exclude` (a set, updated)."""
    out = []
    lo = np.array([ranges[a][0] for a in AXES])
    hi = np.array([ranges[a][1] for a in AXES])
    tries = 0
    while len(out) < count:
        tries += 1
        if tries > 100 * count + 1000:
            raise DatasetError(f"cannot draw {count} distinct poses in ranges {ranges}: the ranges are too small")
        pose = names.quantize(*rng.uniform(lo, hi))
        if pose in exclude or (on_grid is not None and on_grid(pose)):
            continue
        exclude.add(pose)
        out.append(pose)
    return out


def plan(cfg):
    """List of (index, split, pose) for the whole dataset, in index order."""
    for split, n in cfg.counts.items():
        if split not in SPLITS:
            raise DatasetError(f"unknown split {split!r} (splits: {', '.join(SPLITS)})")
        if int(n) != n or n < 0:
            raise DatasetError(f"count of split {split} must be a whole number >= 0, got {n}")
    axes_values = [grid_values(*cfg.ranges[a], cfg.step, a) for a in AXES]
    grid_sets = [set(v) for v in axes_values]
    main = [s for s in ("train", "val", "test") if cfg.counts.get(s, 0)]
    n_main = sum(cfg.counts.get(s, 0) for s in main)
    rng = np.random.default_rng([cfg.seed, 0])
    used = set()
    if cfg.sampling == "grid":
        sizes = [len(v) for v in axes_values]
        total = int(np.prod(sizes))
        if n_main > total:
            raise DatasetError(f"train + val + test = {n_main} poses, but the grid has only {total} "
                               f"({' x '.join(map(str, sizes))}); lower the counts, the step, or use "
                               f"--sampling continuous")
        picks = rng.choice(total, size=n_main, replace=False)
        poses = [tuple(axes_values[k][i] for k, i in enumerate(np.unravel_index(p, sizes))) for p in picks]
        used.update(poses)
    elif cfg.sampling == "continuous":
        poses = _uniform_poses(rng, cfg.ranges, n_main, used)
    else:
        raise DatasetError(f"unknown sampling {cfg.sampling!r} (choose grid or continuous)")

    def on_grid(pose):
        return all(p in s for p, s in zip(pose, grid_sets))

    offgrid = _uniform_poses(np.random.default_rng([cfg.seed, 1]), cfg.ranges,
                             cfg.counts.get("test_offgrid", 0), used, on_grid)
    out, i = [], 0
    it = iter(poses)
    for split in ("train", "val", "test"):
        for _ in range(cfg.counts.get(split, 0)):
            out.append((i, split, next(it)))
            i += 1
    for pose in offgrid:
        out.append((i, "test_offgrid", pose))
        i += 1
    return out


def settings_of(cfg, texture_sha):
    """The JSON settings that decide the content; a resume must match them exactly."""
    from sim.render import DEFAULT_LIGHTS, DEFAULT_MESH, lights_to_json
    return {
        "format": FORMAT,
        "texture_sha256": texture_sha,
        "camera": cfg.camera.to_dict(),
        "ranges": {a: list(cfg.ranges[a]) for a in AXES},
        "step": cfg.step,
        "sampling": cfg.sampling,
        "counts": {s: int(cfg.counts.get(s, 0)) for s in SPLITS},
        "seed": cfg.seed,
        "background": list(cfg.background),
        "lights": lights_to_json(cfg.lights if cfg.lights is not None else DEFAULT_LIGHTS),
        "randomization": cfg.randomization.to_dict(),
        "renderer": {"mesh": list(DEFAULT_MESH), "png_level": PNG_LEVEL, "png_filter": PNG_FILTER},
    } | ({"scene": cfg.scene.settings()} if cfg.scene is not None else {})


def _differences(old, new, prefix=""):
    diffs = []
    for key in sorted(set(old) | set(new)):
        a, b = old.get(key), new.get(key)
        if isinstance(a, dict) and isinstance(b, dict):
            diffs += _differences(a, b, f"{prefix}{key}.")
        elif a != b:
            diffs.append(f"{prefix}{key} (folder: {json.dumps(a)}, now: {json.dumps(b)})")
    return diffs


def _frames_to_render(poses, out, camera, workers):
    """(tasks, damaged): the frames to render as (index, path, pose), and 'split/name (problem)' for each
    existing frame that failed sim.frames.frame_problem (a file is not taken as done for existing: a
    crash or a full disk can leave one empty or cut short). Frames are checked on `workers` threads
    (decoding releases the GIL)."""
    paths = [os.path.join(out, split, names.format_name(*pose)) for _, split, pose in poses]
    present = [i for i, p in enumerate(paths) if os.path.exists(p)]
    with ThreadPoolExecutor(max(1, workers)) as ex:
        problems = dict(zip(present, ex.map(lambda i: frame_problem(paths[i], camera.width, camera.height),
                                            present)))
    tasks, damaged = [], []
    for i, (index, split, pose) in enumerate(poses):
        if i in problems and problems[i] is None:
            continue
        if problems.get(i) is not None:
            damaged.append(f"{os.path.relpath(paths[i], out)} ({problems[i]})")
        tasks.append((index, paths[i], pose))
    return tasks, damaged


def _write_record(out, record):
    write_atomic(os.path.join(out, RECORD), (json.dumps(record, indent=1) + "\n").encode())


# ---- workers ---------------------------------------------------------------

_WORKER = {}


def _worker_init(cfg, single_thread_gl):
    """Create this process's Renderer once (one per worker process)."""
    if single_thread_gl:
        # One rasteriser thread per worker, and no OpenCV thread pool: the workers already fill the cores.
        os.environ["LP_NUM_THREADS"] = "1"
        import cv2
        cv2.setNumThreads(1)
    from sim.render import Renderer, DEFAULT_LIGHTS
    if cfg.scene is not None:
        from sim.scene_render import SceneRenderer
        _WORKER["renderer"] = SceneRenderer(cfg.texture, cfg.scene)
    else:
        _WORKER["renderer"] = Renderer(cfg.texture, cfg.camera, background=cfg.background,
                                       lights=cfg.lights if cfg.lights is not None else DEFAULT_LIGHTS)
    _WORKER["cfg"] = cfg


def _render_task(task):
    """Render and encode one frame and write it to a temporary file; returns (temporary, path).

    The parent commits it (sim.frames.commit_temporary: fsync, rename) on its own threads, so a
    worker goes on rendering while the disk catches up (an fsync is about 6 ms here, half a
    frame's rendering)."""
    from sim.randomize import render_frame
    index, path, pose = task
    cfg = _WORKER["cfg"]
    rng = np.random.default_rng([cfg.seed, 2, index])
    if cfg.scene is not None:
        img, _ = _WORKER["renderer"].frame(pose, rng)
    else:
        img = render_frame(_WORKER["renderer"], pose, cfg.randomization, rng)
    return write_temporary(path, encode_png(img)), path


def frame_truth(cfg, index, pose):
    """The truth.jsonl line of frame `index` (a dict), from its generator alone (no rendering).

    circle: the sphere's outline [cx, cy, r] in the undistorted frame, continuous pixel coordinates.
    With a scene, "scene" holds the frame's whole draw (sim/scene.draw).
    """
    rng = np.random.default_rng([cfg.seed, 2, index])
    line = {"file": names.format_name(*pose), "pose": list(pose)}
    if cfg.scene is not None:
        from sim.scene import draw
        params = draw(cfg.scene, rng)
        line["circle"] = params["circle"]
        line["scene"] = {k: v for k, v in params.items() if k != "circle"}
        return line
    from sim.randomize import sample
    from sim.render import DEFAULT_LIGHTS
    cam = cfg.camera
    du, dv, scale = 0.0, 0.0, 1.0
    if cfg.randomization.enabled:  # the same draws, in the same order, as randomize.render_frame
        fp = sample(cfg.randomization, rng, cfg.lights if cfg.lights is not None else DEFAULT_LIGHTS,
                    cfg.background)
        (du, dv), scale = fp.offset_px, fp.scale
    u0, v0 = cam.principal
    line["circle"] = [u0 + du, v0 + dv, cam.radius_px * scale]
    return line


def write_truth(cfg, out, poses):
    """Write OUT/<split>/truth.jsonl (atomically) for every frame of the plan, in index order."""
    lines = {}
    for index, split, pose in poses:
        lines.setdefault(split, []).append(json.dumps(frame_truth(cfg, index, pose)))
    for split, text in lines.items():
        write_atomic(os.path.join(out, split, TRUTH), ("\n".join(text) + "\n").encode())


def _pool_context():
    """Worker processes from a fresh fork server, never forked from this process.

    Forking a process that already holds an OpenGL context (a caller that rendered
    in-process first) deadlocks the child on the rasteriser's threads' locks; the
    fork server is a clean process that has imported the renderer but opened no
    context, so workers still start in milliseconds.
    """
    methods = multiprocessing.get_all_start_methods()
    if "forkserver" in methods:
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(["sim.dataset", "sim.render", "sim.randomize"])
        return ctx
    return multiprocessing.get_context("spawn")


def build(cfg, out, *, workers=None, progress=True, command=None, log=print, engine="local", ray_address=None):
    """Render the dataset of `cfg` into folder `out`; only missing frames are rendered (resume).

    engine: "local" (a pool of `workers` processes here) or "ray" (Ray tasks, sim/engine_ray.py: the
    cluster at `ray_address` or RAY_ADDRESS, else a local instance of `workers` CPUs); same frames.

    Returns the record written to OUT/dataset.json.
    """
    if os.path.exists(out) and not os.path.isdir(out):
        raise DatasetError(f"{out}: exists and is not a folder; --out names the dataset folder "
                           f"(a new or empty one, or a dataset to resume)")
    if not os.path.isfile(cfg.texture):
        raise DatasetError(f"{cfg.texture}: texture file not found")
    from sim.render import load_texture
    load_texture(cfg.texture)  # check it early, with a message naming the file
    tex_sha = sha256_file(cfg.texture)
    settings = settings_of(cfg, tex_sha)
    poses = plan(cfg)

    record_path = os.path.join(out, RECORD)
    if os.path.exists(record_path):
        try:
            with open(record_path, encoding="utf-8") as f:
                old = json.load(f)
        except (OSError, json.JSONDecodeError) as e:
            raise DatasetError(f"{record_path}: unreadable dataset record ({e}); remove the folder or "
                               f"choose another --out") from None
        diffs = _differences(old.get("settings", {}), settings)
        if diffs:
            raise DatasetError(f"{out} holds a dataset made with different arguments; refusing to resume "
                               f"into it. Differences: " + "; ".join(diffs))
        created = old.get("created_utc")
    else:
        if os.path.isdir(out) and os.listdir(out):
            raise DatasetError(f"{out} is not empty and has no {RECORD}: not a dataset folder; "
                               f"choose an empty or new --out")
        created = None
    try:
        os.makedirs(out, exist_ok=True)
        for split in SPLITS:
            if settings["counts"][split]:
                os.makedirs(os.path.join(out, split), exist_ok=True)
                remove_stale_temporaries(os.path.join(out, split))
    except OSError as e:   # a path through a file, no permission, a split name taken by a file
        raise DatasetError(f"{e.filename}: cannot create the dataset folder ({e.strerror})") from None

    record = {
        "format": FORMAT,
        "command": command if command is not None else shlex.join(sys.argv),
        "created_utc": created or time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "texture": {"path": cfg.texture, "sha256": tex_sha},
        "settings": settings,
        "counts": settings["counts"],
        "complete": False,
    }
    _write_record(out, record)

    requested_workers = workers
    workers = workers or len(os.sched_getaffinity(0))
    camera = cfg.scene.camera if getattr(cfg, "scene", None) is not None else cfg.camera   # the frames' size
    tasks, broken = _frames_to_render(poses, out, camera, workers)
    done_before = len(poses) - len(tasks)
    if done_before or broken:
        log(f"resuming: {done_before} of {len(poses)} frames already in {out}")
    if broken:
        log(f"{len(broken)} frame{'s' if len(broken) > 1 else ''} damaged, rendered again: " +
            "; ".join(broken[:10]) + (f"; and {len(broken) - 10} more" if len(broken) > 10 else ""))

    workers = max(1, min(workers, len(tasks) or 1))
    t0 = time.time()
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=len(poses), initial=done_before, unit="frame", desc="render", smoothing=0.05)
    committer = ThreadPoolExecutor(COMMIT_THREADS)
    commits = []
    try:
        if engine == "ray":
            from dataclasses import replace
            from sim import engine_ray
            # Workers may run elsewhere with another working directory: absolute paths only.
            remote = [(i, os.path.abspath(p), pose) for i, p, pose in tasks]
            key = hashlib.sha256(json.dumps([settings, os.path.abspath(out)], sort_keys=True).encode()).hexdigest()
            workers = engine_ray.render(replace(cfg, texture=os.path.abspath(cfg.texture)), remote, key,
                                        address=ray_address, workers=requested_workers,
                                        on_frames=bar.update if bar else None, log=log) if tasks else 0
        elif engine != "local":
            raise DatasetError(f"unknown engine {engine!r} (choose local or ray)")
        elif workers == 1:
            _worker_init(cfg, single_thread_gl=False)
            for tmp, path in map(_render_task, tasks):
                commits.append(committer.submit(commit_temporary, tmp, path))
                if bar:
                    bar.update(1)
        else:
            ctx = _pool_context()
            with ctx.Pool(workers, initializer=_worker_init, initargs=(cfg, True)) as pool:
                for tmp, path in pool.imap_unordered(_render_task, tasks, chunksize=4):
                    commits.append(committer.submit(commit_temporary, tmp, path))
                    if bar:
                        bar.update(1)
        for c in commits:
            c.result()          # a failed commit (disk full, ...) fails the run: never marked complete
    finally:
        committer.shutdown(wait=True)   # frames rendered before an interruption are still committed
        if bar:
            bar.close()
    write_truth(cfg, out, poses)
    elapsed = time.time() - t0

    record["complete"] = True
    record["finished_utc"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    record["last_run"] = {"rendered": len(tasks), "damaged_rendered_again": len(broken), "engine": engine,
                          "workers": workers,
                          "seconds": round(elapsed, 3),
                          "frames_per_s": round(len(tasks) / elapsed, 2) if elapsed > 0 and tasks else None}
    _write_record(out, record)
    return record
