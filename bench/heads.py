"""Euler head vs 6-D head, side by side, on several seeds (docs/bench/training.md).

    .venv/bin/python bench/heads.py --data DATASET [--seeds 0 1] [--size 128] [--epochs 20]

Trains MobileNetV2 with each head on the same P1 dataset (`sim dataset`
folder with train/, val/, test_offgrid/), the paper's recipe otherwise
(AdamW 5e-4, cosine, MAE + pseudo-Huber, no augmentation), one run per head
and seed, and writes a table of validation and off-grid errors per run, the
mean per head and the per-seed difference. Finished runs are kept and not
trained again, so the command resumes; --parallel N runs N at once (one
torch thread each).
"""
import argparse
import datetime
import json
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HEADS = ("euler", "rot6d")


def get_args_parser():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True, help="P1 dataset folder (sim dataset) of one texture")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="training seeds (default 0 1)")
    ap.add_argument("--size", type=int, default=128, help="input size in px (default 128)")
    ap.add_argument("--epochs", type=int, default=20, help="epochs (default 20, the paper's)")
    ap.add_argument("--parallel", type=int, default=1, help="runs at once, one torch thread each (default 1)")
    ap.add_argument("--out", default=str(ROOT / "build" / "heads"), help="runs and report.md (default build/heads)")
    return ap


def run_cmd(data, head, seed, args, out):
    return [sys.executable, "-m", "training.cli", "train", "--data", str(data), "--arch", "mobilenet_v2",
            "--head", head, "--size", str(args.size), "--epochs", str(args.epochs), "--seed", str(seed),
            "--threads", "1", "--no-progress", "--no-export", "--eval-splits", "val", "test_offgrid",
            "--out", str(out)]


def main(args):
    data = Path(args.data)
    if not (data / "train").is_dir() or not (data / "val").is_dir():
        sys.exit(f"heads: {data}: not a dataset folder (needs train/ and val/)")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    todo, running = [], []
    for seed in args.seeds:
        for head in HEADS:
            run = out / f"{head}_seed{seed}"
            if not (run / "metrics.json").exists():
                cmd = run_cmd(data, head, seed, args, run)
                if (run / "checkpoint.pth").exists():
                    cmd += ["--resume", str(run / "checkpoint.pth")]
                todo.append((run, cmd))
    t0 = time.time()
    while todo or running:
        while todo and len(running) < args.parallel:
            run, cmd = todo.pop(0)
            run.mkdir(parents=True, exist_ok=True)
            print(f"heads: start {run.name}", flush=True)
            log = open(run.parent / f"{run.name}.log", "a")
            running.append((run, subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT), log))
        time.sleep(5)
        for item in list(running):
            run, proc, log = item
            if proc.poll() is not None:
                log.close()
                running.remove(item)
                if proc.returncode:
                    sys.exit(f"heads: {run.name} failed ({proc.returncode}), see {run.parent / (run.name + '.log')}")
                print(f"heads: done {run.name} ({(time.time() - t0) / 60:.1f} min)", flush=True)
    write_report(args, data, out)


def write_report(args, data, out):
    rows, by_head = [], {h: {} for h in HEADS}
    for seed in args.seeds:
        for head in HEADS:
            m = json.loads((out / f"{head}_seed{seed}" / "metrics.json").read_text())
            r = json.loads((out / f"{head}_seed{seed}" / "run.json").read_text())
            by_head[head][seed] = m
            rows.append(f"| {head} | {seed} | {m['val']['mae']:.3f} | {m['val']['rmse']:.3f} | "
                        f"{m['val']['geodesic_mean']:.3f} | {m['test_offgrid']['mae']:.3f} | "
                        f"{m['test_offgrid']['rmse']:.3f} | {r.get('train_s', 0) / 60:.1f} |")
    md = ["# Euler head vs 6-D head", "",
          f"- Command: `.venv/bin/python bench/heads.py --data {data} --seeds {' '.join(map(str, args.seeds))} "
          f"--size {args.size} --epochs {args.epochs} --parallel {args.parallel}`",
          f"- Date: {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC; machine: "
          f"{platform.machine()}, CPU, 1 torch thread per run",
          f"- MobileNetV2, {args.size} px, {args.epochs} epochs, AdamW 5e-4, cosine, batch 32, MAE + "
          "pseudo-Huber, no augmentation (protocol P1 apart from the head)", "",
          "| head | seed | val MAE | val RMSE | val geodesic mean | off-grid MAE | off-grid RMSE | train min |",
          "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |", *rows, ""]
    for split, name in (("val", "validation"), ("test_offgrid", "off-grid")):
        means = {h: statistics.mean(by_head[h][s][split]["mae"] for s in args.seeds) for h in HEADS}
        diffs = [by_head["rot6d"][s][split]["mae"] - by_head["euler"][s][split]["mae"] for s in args.seeds]
        wins = sum(d < 0 for d in diffs)
        md.append(f"- {name} MAE, mean over seeds: euler {means['euler']:.3f}, rot6d {means['rot6d']:.3f}; "
                  f"rot6d minus euler per seed: {', '.join(f'{d:+.3f}' for d in diffs)} "
                  f"(rot6d lower on {wins} of {len(diffs)})")
    md.append("")
    (out / "report.md").write_text("\n".join(md))
    print("\n".join(md))
    print(f"heads: wrote {out / 'report.md'}")


if __name__ == "__main__":
    main(get_args_parser().parse_args())
