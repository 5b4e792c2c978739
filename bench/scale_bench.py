#!/usr/bin/env python3
"""Scale-out costs on this machine: `sim dataset` local vs Ray, `posetrain train` under torchrun.

    .venv/bin/python bench/scale_bench.py [--frames 240] [--rounds 2] [--scene sim/scenes/train.json]
                                          [--train-frames 384] [--json FILE] [--skip-render] [--skip-train]

Rendering: the same plan (P1 proportions, reference camera 640 x 512) with the local engine and
with the Ray engine, 1 and 2 workers. Ray runs on a head this script starts once with `ray start
--head` (2 CPUs), as a lab's cluster would be running already; each run connects to it (`--workers
N`: N tasks at a time), so a run's time includes connecting and starting its worker processes, as
the local engine's includes starting its pool. The four runs are interleaved, in the opposite order
in every other round, so that a machine shared with other work loads both engines alike; the ratio
Ray / local of each pair is the result. The frames of both engines are compared byte for byte.

Each round ends with a Ray run without an address: the run starts its own local instance (2 CPUs)
and stops it, what `sim dataset --engine ray` does on a machine without a cluster.

Per-frame cost of a rig scene (`--scene`): one local worker in this process, CPU time per frame
(independent of the machine's load), from which the report derives a 64-CPU cluster's hours for a
million frames.

Training: one epoch of `posetrain train` on a small quick-profile set (320 x 256 frames, 64 px,
MobileNetV2, batch 32) under `torchrun --standalone`: 1 process x 1 thread, 1 process x 2 threads,
2 processes x 1 thread (gloo), interleaved rounds; throughput = training frames / epoch seconds.
"""
import argparse
import csv
import hashlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import uuid

from machine import load_1min, machine

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.dirname(sys.executable)
TEXTURE = os.path.join(REPO, "build", "textures", "Texture_3_color.png")


def counts_for(frames):
    p1 = {"train": 1600, "val": 597, "test": 100, "test_offgrid": 100}
    scale = frames / sum(p1.values())
    return {k: int(round(v * scale)) for k, v in p1.items()}


def digest(folder):
    out = {}
    for root, _, files in os.walk(folder):
        for name in files:
            if name.endswith(".png"):
                with open(os.path.join(root, name), "rb") as f:
                    out[os.path.relpath(os.path.join(root, name), folder)] = hashlib.sha256(f.read()).hexdigest()
    return out


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Head:
    """A Ray head on this machine (`ray start --head --block`), stopped by signalling that process."""

    def __init__(self, cpus):
        self.temp = tempfile.mkdtemp(prefix="ray", dir="/tmp")
        os.environ.update(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=uuid.uuid4().hex)
        port = free_port()
        self.log = open(os.path.join(self.temp, "head.log"), "w")
        self.proc = subprocess.Popen(
            [os.path.join(BIN, "ray"), "start", "--head", "--block", "--port", str(port), "--num-cpus", str(cpus),
             "--include-dashboard", "false", "--disable-usage-stats", "--temp-dir", self.temp,
             "--dashboard-agent-listen-port", str(free_port())],
            stdout=self.log, stderr=subprocess.STDOUT, start_new_session=True)
        self.address = f"127.0.0.1:{port}"
        deadline = time.time() + 120
        while "This command will now block" not in open(self.log.name).read():
            if self.proc.poll() is not None or time.time() > deadline:
                raise RuntimeError("ray head did not start: " + open(self.log.name).read()[-2000:])
            time.sleep(0.5)

    def stop(self):
        self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(60)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
        self.log.close()
        shutil.rmtree(self.temp, ignore_errors=True)


def render_run(engine, workers, frames, tmp, address=None, scene=None):
    from sim.dataset import DatasetConfig, build
    out = os.path.join(tmp, f"{engine}-w{workers}-{uuid.uuid4().hex[:6]}")
    cfg = DatasetConfig(texture=TEXTURE, counts=counts_for(frames))
    if scene is not None:
        cfg = DatasetConfig(texture=TEXTURE, counts=counts_for(frames), camera=scene.camera, scene=scene)
    t0, c0 = time.perf_counter(), time.process_time()
    rec = build(cfg, out, workers=workers, progress=False, command="bench/scale_bench.py", log=lambda *a: None,
                engine=engine, ray_address=address)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    n = rec["last_run"]["rendered"]
    res = {"engine": engine, "workers": workers, "frames": n, "seconds": round(wall, 2),
           "frames_per_s": round(n / wall, 2), "load_1min": round(load_1min(), 1)}
    if engine == "local" and workers == 1:
        res["cpu_ms_per_frame"] = round(1000 * cpu / n, 2)   # rendered in this process
    return res, out


def bench_render(args, tmp):
    head = Head(cpus=2)
    runs, identical = [], True
    try:
        for r in range(args.rounds):
            order = [("local", 1), ("ray", 1), ("local", 2), ("ray", 2)]
            if r % 2:
                order = [(e, w) for w in (1, 2) for e in ("ray", "local")]
            folders = {}
            for engine, w in order:
                res, out = render_run(engine, w, args.frames, tmp, head.address if engine == "ray" else None)
                res["round"] = r + 1
                runs.append(res)
                print(f"  round {r + 1} {engine:5s} {w} worker{'s' if w > 1 else ' '}: {res['frames_per_s']:6.2f} "
                      f"frames/s ({res['seconds']} s, load {res['load_1min']})", flush=True)
                folders[(engine, w)] = out
            # Last, the Ray engine without a cluster: the run starts (and stops) its own local instance.
            res, out = render_run("ray", 2, args.frames, tmp, None)
            res.update(round=r + 1, engine="ray-own-instance")
            runs.append(res)
            print(f"  round {r + 1} ray, own local instance, 2 workers: {res['frames_per_s']:6.2f} frames/s "
                  f"({res['seconds']} s, load {res['load_1min']})", flush=True)
            folders[("ray-own-instance", 2)] = out
            for w in (1, 2):
                identical &= digest(folders[("local", w)]) == digest(folders[("ray", w)])
            identical &= digest(folders[("local", 2)]) == digest(folders[("ray-own-instance", 2)])
            for out in folders.values():
                shutil.rmtree(out)
    finally:
        head.stop()
    ratios = {}
    for w in (1, 2):
        pairs = []
        for r in range(1, args.rounds + 1):
            fps = {x["engine"]: x["frames_per_s"] for x in runs if x["round"] == r and x["workers"] == w}
            pairs.append(round(fps["ray"] / fps["local"], 3))
        ratios[w] = pairs
    return {"runs": runs, "ray_over_local": ratios, "frames_identical": identical}


def bench_scene(args, tmp):
    from sim.scene import load_scene
    res, out = render_run("local", 1, args.scene_frames, tmp, scene=load_scene(args.scene))
    shutil.rmtree(out)
    return res


def make_train_set(args, tmp):
    cam = os.path.join(tmp, "quick_camera.json")
    with open(cam, "w") as f:
        json.dump({"width": 320, "height": 256, "focal_mm": 8.0}, f)
    out = os.path.join(tmp, "train_set")
    r = subprocess.run([sys.executable, "-m", "sim.cli", "dataset", "--texture", TEXTURE, "--camera", cam,
                        "--out", out, "--sampling", "continuous", "--train", str(args.train_frames), "--val", "16",
                        "--test", "0", "--offgrid-test", "0", "--quiet"], capture_output=True, text=True)
    if r.returncode:
        raise RuntimeError(r.stderr)
    return out


def train_run(data, procs, threads, tmp):
    out = os.path.join(tmp, f"run-p{procs}-t{threads}-{uuid.uuid4().hex[:6]}")
    env = dict(os.environ, OMP_NUM_THREADS=str(threads))
    cmd = [os.path.join(BIN, "torchrun"), "--standalone", "--nproc-per-node", str(procs), "--no-python",
           os.path.join(BIN, "posetrain"), "train", "--data", data, "--out", out, "--arch", "mobilenet_v2",
           "--size", "64", "--epochs", "1", "-b", "32", "--device", "cpu", "--threads", str(threads),
           "--no-progress", "--no-export", "--eval-splits", "val", "--workers", "1"]
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if r.returncode:
        raise RuntimeError(r.stdout[-2000:] + r.stderr[-2000:])
    row = list(csv.DictReader(open(os.path.join(out, "log.csv"))))[-1]
    n = json.load(open(os.path.join(out, "run.json")))["train_frames"]
    shutil.rmtree(out)
    epoch_s = float(row["epoch_s"])
    return {"processes": procs, "threads_each": threads, "train_frames": n, "epoch_s": epoch_s,
            "frames_per_s": round(n / epoch_s, 2), "command_s": round(wall, 1), "load_1min": round(load_1min(), 1)}


def bench_train(args, tmp):
    data = make_train_set(args, tmp)
    configs = [(1, 1), (1, 2), (2, 1)]
    train_run(data, 1, 1, tmp)      # builds the crop cache, so that no timed run pays for it
    runs = []
    for r in range(args.rounds):
        for procs, threads in (configs if r % 2 == 0 else configs[::-1]):
            res = train_run(data, procs, threads, tmp)
            res["round"] = r + 1
            runs.append(res)
            print(f"  round {r + 1} {procs} process{'es' if procs > 1 else '  '} x {threads} thread"
                  f"{'s' if threads > 1 else ' '}: {res['frames_per_s']:6.2f} frames/s (epoch {res['epoch_s']} s, "
                  f"load {res['load_1min']})", flush=True)
    ratios = {}
    for r in range(1, args.rounds + 1):
        fps = {(x["processes"], x["threads_each"]): x["frames_per_s"] for x in runs if x["round"] == r}
        ratios[r] = {"2x1 / 1x1": round(fps[(2, 1)] / fps[(1, 1)], 3), "2x1 / 1x2": round(fps[(2, 1)] / fps[(1, 2)], 3)}
    return {"runs": runs, "ratios_per_round": ratios}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=240, help="frames per rendering run (P1 proportions)")
    p.add_argument("--rounds", type=int, default=2, help="interleaved rounds of every configuration")
    p.add_argument("--scene", default=os.path.join(REPO, "sim", "scenes", "train.json"),
                   help="rig scene whose per-frame cost is measured")
    p.add_argument("--scene-frames", type=int, default=60, help="frames of the rig-scene run")
    p.add_argument("--train-frames", type=int, default=384, help="training frames of the torchrun runs")
    p.add_argument("--skip-render", action="store_true", help="no rendering runs")
    p.add_argument("--skip-train", action="store_true", help="no training runs")
    p.add_argument("--json", help="also write the results to this JSON file")
    args = p.parse_args(argv)
    if not os.path.exists(TEXTURE):
        raise SystemExit(f"{TEXTURE} missing: make textures (or `textures generate --out build/textures`)")
    result = {**machine(), "load_1min_start": round(load_1min(), 1), "command": " ".join(sys.argv)}
    with tempfile.TemporaryDirectory(prefix="scale_bench-") as tmp:
        if not args.skip_render:
            print(f"rendering: {args.frames} frames per run, reference camera, Texture_3_color", flush=True)
            result["render"] = bench_render(args, tmp)
            print(f"  Ray / local frames/s per round: 1 worker {result['render']['ray_over_local'][1]}, "
                  f"2 workers {result['render']['ray_over_local'][2]}; frames identical: "
                  f"{result['render']['frames_identical']}", flush=True)
            result["scene"] = bench_scene(args, tmp)
            ms = result["scene"]["cpu_ms_per_frame"]
            print(f"rig scene {os.path.relpath(args.scene, REPO)}: {ms} ms CPU per frame (1 local worker)", flush=True)
        if not args.skip_train:
            print(f"training: {args.train_frames} frames, 320 x 256, 64 px, MobileNetV2, batch 32, 1 epoch", flush=True)
            result["train"] = bench_train(args, tmp)
            print(f"  ratios per round: {result['train']['ratios_per_round']}", flush=True)
    result["load_1min_end"] = round(load_1min(), 1)
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(result, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
