"""The paper's texture study (§3, Tables 1 and 2): six textures, one protocol.

For each of Texture_{1,2,3}_{bw,color}: render a dataset (`sim dataset`), train,
evaluate on validation, test and off-grid test, then write OUT/report.md with
a Table 1 (validation) and a Table 2 (test) in the paper's columns, the paper's
numbers beside ours, the ordering of the textures by error, and figures.
Resumable: a texture whose run finished (OUT/runs/<texture>/metrics.json and
run.json) is not trained again, an unfinished run resumes from its
checkpoint.pth, and `sim dataset` resumes its own folders.

Profiles:
- quick: the P1 pose split (1,600 / 597 / 100 grid poses + 100 off-grid),
  frames at half the reference camera's resolution (320 x 256, f 8 mm: the
  same view, the sphere 133 px across), 64 px input, MobileNetV2, 8 epochs:
  minutes per texture on a 2-core CPU.
- p1: the paper's protocol, 128 px, MobileNetV2, 20 epochs: minutes per
  texture on a GPU, about 20 minutes on a 2-core CPU (docs/bench/training.md).
- smoke: a few frames, one epoch: checks the plumbing only.
"""
import datetime
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from . import metrics as M
from .export import ExportMismatch
from . import plots
from .train import options, train

TEXTURES = ("Texture_1_bw", "Texture_1_color", "Texture_2_bw", "Texture_2_color", "Texture_3_bw",
            "Texture_3_color")

PROFILES = {
    "quick": {"size": 64, "arch": "mobilenet_v2", "epochs": 8, "batch_size": 32,
              "camera": {"width": 320, "height": 256, "focal_mm": 8.0},
              "dataset": ["--train", "1600", "--val", "597", "--test", "100", "--offgrid-test", "100"]},
    "smoke": {"size": 32, "arch": "mobilenet_v3_small", "epochs": 1, "batch_size": 8,
              "dataset": ["--train", "32", "--val", "16", "--test", "8", "--offgrid-test", "8"]},
    "p1": {"size": 128, "arch": "mobilenet_v2", "epochs": 20, "batch_size": 32,
           "dataset": ["--train", "1600", "--val", "597", "--test", "100", "--offgrid-test", "100"]},
}

# The paper's Table 1 (validation Err/Std per axis, MAE, RMSE) and Table 2 (test MAE, RMSE, Std per axis).
PAPER_T1 = {
    "Texture_1_bw": ([1.7485, 0.663, 1.121], [0.706, 0.529, 0.873], 1.178, 1.469),
    "Texture_1_color": ([0.769, 0.654, 1.499], [0.493, 0.454, 1.534], 0.974, 1.189),
    "Texture_2_bw": ([0.764, 0.663, 1.097], [0.539, 0.540, 0.873], 0.842, 1.078),
    "Texture_2_color": ([0.710, 0.658, 1.004], [0.568, 0.874, 0.657], 0.791, 1.037),
    "Texture_3_bw": ([0.305, 0.654, 0.517], [0.246, 0.449, 0.426], 0.492, 0.661),
    "Texture_3_color": ([0.284, 0.367, 0.596], [0.211, 0.242, 0.466], 0.416, 0.543),
}
PAPER_T2 = {
    "Texture_1_bw": (1.052, 1.411, [0.997, 0.625, 0.916]),
    "Texture_1_color": (1.32, 1.543, [0.649, 0.48, 0.632]),
    "Texture_2_bw": (1.039, 1.335, [0.6, 0.639, 1.059]),
    "Texture_2_color": (1.008, 1.237, [0.659, 0.737, 0.762]),
    "Texture_3_bw": (0.758, 0.911, [0.327, 0.665, 0.483]),
    "Texture_3_color": (0.731, 0.876, [0.421, 0.422, 0.549]),
}


def _run(cmd, log):
    print("+ " + " ".join(cmd), flush=True)
    with open(log, "a") as f:
        r = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT)
    if r.returncode:
        raise RuntimeError(f"command failed ({r.returncode}), see {log}: {' '.join(cmd)}")


def ensure_textures(args, out):
    tdir = Path(args.texture_dir) if args.texture_dir else out / "textures"
    wanted = args.textures or list(TEXTURES)
    missing = [t for t in wanted if not (tdir / f"{t}.png").exists()]
    if missing and args.texture_dir:
        raise ValueError(f"{tdir}: missing {', '.join(t + '.png' for t in missing)}")
    if missing:
        tdir.mkdir(parents=True, exist_ok=True)
        _run([sys.executable, "-m", "textures.cli", "generate", "--out", str(tdir)], out / "study.log")
    return tdir, wanted


def _read_preds(run_dir, split):
    p = run_dir / f"predictions_{split}.csv"
    if not p.exists():
        return None
    a = np.genfromtxt(p, delimiter=",", skip_header=1, usecols=range(1, 7))
    a = np.atleast_2d(a)
    return a[:, 3:6], a[:, 0:3]


def run_study(args):
    if args.profile not in PROFILES:
        raise ValueError(f"unknown profile {args.profile!r}; valid: {', '.join(PROFILES)}")
    unknown = [t for t in (args.textures or []) if t not in TEXTURES]
    if unknown:
        raise ValueError(f"unknown texture(s) {', '.join(unknown)}; valid: {', '.join(TEXTURES)}")
    prof = dict(PROFILES[args.profile])
    if args.arch:
        prof["arch"] = args.arch
    if args.epochs:
        prof["epochs"] = args.epochs
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    tdir, textures = ensure_textures(args, out)
    cam = []
    if prof.get("camera"):
        cam_file = out / f"camera_{args.profile}.json"
        cam_file.write_text(json.dumps(prof["camera"]) + "\n")
        cam = ["--camera", str(cam_file)]
    if getattr(args, "engine", "local") == "ray":   # each texture's run a Ray task (study_ray.py)
        from .study_ray import run_textures
        done = run_textures(textures, tdir, out, prof, cam, args)
    else:
        done = {tex: run_texture(tex, tdir, out, prof, cam, args) for tex in textures}
    results = {tex: done[tex][0] for tex in textures}
    timings = {tex: done[tex][1] for tex in textures}
    write_report(out, args.profile, prof, textures, results, timings, time.time() - t0)


def run_texture(tex, tdir, out, prof, cam, args, workers=None):
    """One texture: its dataset (resumed), its training (skipped when finished, else resumed from
    its checkpoint) and evaluation; returns (metrics, timings). workers: the dataset's --workers
    (None: every core)."""
    ds = out / "datasets" / tex
    run = out / "runs" / tex
    t_tex = time.time()
    _run([sys.executable, "-m", "sim.cli", "dataset", "--texture", str(tdir / f"{tex}.png"), "--out", str(ds),
          "--seed", str(args.seed), "--quiet", *cam, *prof["dataset"],
          *(["--workers", str(workers)] if workers else [])], out / "study.log")
    if (run / "metrics.json").exists() and (run / "run.json").exists():
        print(f"study: {tex}: finished run found in {run}, not retrained", flush=True)
    else:
        ck = run / "checkpoint.pth"
        opts = options(ds, run, texture=tex, arch=prof["arch"], size=prof["size"], epochs=prof["epochs"],
                       batch_size=prof["batch_size"], seed=args.seed, device=args.device,
                       threads=args.threads, workers=args.workers, progress=args.progress,
                       cache=args.cache, resume=str(ck) if ck.exists() else None)
        try:
            train(opts)
        except ExportMismatch as e:  # metrics are written; the report says the export failed
            print(f"study: {tex}: error: {e}", file=sys.stderr, flush=True)
            (run / "export_error.txt").write_text(str(e) + "\n")
    timing = json.loads((run / "run.json").read_text())
    timing["study_s"] = round(time.time() - t_tex, 1)
    return json.loads((run / "metrics.json").read_text()), timing


def _order(textures, results, split):
    have = [t for t in textures if split in results[t]]
    return sorted(have, key=lambda t: results[t][split]["mae"])


def write_report(out, profile, prof, textures, results, timings, wall_s):
    f3 = lambda v: f"{v:.3f}"
    lines = [f"# Texture study, profile `{profile}`", "",
             f"Date {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC; "
             f"{prof['arch']}, {prof['size']} px, {prof['epochs']} epochs, batch {prof['batch_size']}, AdamW 5e-4, "
             f"cosine, MAE + pseudo-Huber (delta 1 deg), no augmentation; dataset `sim dataset "
             f"{' '.join(prof['dataset'])}`" + (f", camera {json.dumps(prof['camera'])}" if prof.get("camera") else "")
             + f"; device {timings[textures[0]].get('device', '?')}; "
             f"study wall time {wall_s / 60:.1f} min.", "",
             "All values in degrees; metrics as conventions.md defines them (the paper's).", "",
             "## Table 1: validation", "",
             "| Texture | Err_X | Err_Y | Err_Z | Std_X | Std_Y | Std_Z | MAE | RMSE | geo mean | paper MAE | paper RMSE |",
             "| --- |" + " ---: |" * 11]
    for t in textures:
        v = results[t].get("val")
        if not v:
            continue
        p = PAPER_T1.get(t)
        lines.append(f"| {t} | " + " | ".join(map(f3, v["err"] + v["std"] + [v["mae"], v["rmse"], v["geodesic_mean"]]))
                     + f" | {p[2]:.3f} | {p[3]:.3f} |")
    lines += ["", "## Table 2: test (grid) and off-grid test", "",
              "| Texture | Val MAE | Val RMSE | Test MAE | Test RMSE | Test Std (X, Y, Z) | Off-grid MAE "
              "| Off-grid RMSE | paper Test MAE | paper Test RMSE | train s |",
              "| --- |" + " ---: |" * 10]
    for t in textures:
        r = results[t]
        v, te, og = r.get("val"), r.get("test"), r.get("test_offgrid")
        na = "–"
        p = PAPER_T2.get(t)
        lines.append(" | ".join([
            f"| {t}", f3(v["mae"]) if v else na, f3(v["rmse"]) if v else na,
            f3(te["mae"]) if te else na, f3(te["rmse"]) if te else na,
            ", ".join(map(f3, te["std"])) if te else na,
            f3(og["mae"]) if og else na, f3(og["rmse"]) if og else na,
            f"{p[0]:.3f}", f"{p[1]:.3f}", f"{timings[t].get('train_s', 0):.0f}"]) + " |")
    lines += ["", "## Ordering by error (best first)", ""]
    for split, name in (("val", "validation MAE"), ("test_offgrid", "off-grid test MAE"), ("test", "test MAE")):
        order = _order(textures, results, split)
        if order:
            lines.append(f"- {name}: " + " < ".join(f"{t} ({results[t][split]['mae']:.3f})" for t in order))
    paper_order = sorted(PAPER_T1, key=lambda t: PAPER_T1[t][2])
    lines.append("- the paper, validation MAE: " + " < ".join(f"{t} ({PAPER_T1[t][2]:.3f})" for t in paper_order))
    lines += ["", "## The paper's findings, checked", ""]
    lines += findings(textures, results)
    # figures
    rows = [(t, results[t]) for t in textures]
    plots.study_bars(rows, out / "study_mae.png")
    box_rows = []
    for t in textures:
        pr = _read_preds(out / "runs" / t, "val")
        if pr is not None:
            box_rows.append((t, pr[0], pr[1]))
    if box_rows:
        plots.study_box(box_rows, out / "study_box_val.png")
    errs = [(t, (out / "runs" / t / "export_error.txt").read_text().strip()) for t in textures
            if (out / "runs" / t / "export_error.txt").exists()]
    if errs:
        lines += ["", "## ONNX export failures", ""] + [f"- {t}: {e}" for t, e in errs]
    lines += ["", "## Figures", "", "![MAE per texture and split](study_mae.png)", "",
              "![validation error per texture](study_box_val.png)", "",
              "Per texture (Fig. 3, 4, 6 of the paper): `runs/<texture>/*_fig*.png`; tables in "
              "`runs/<texture>/tables.md`.", ""]
    (out / "report.md").write_text("\n".join(lines))
    M.save_json(out / "study.json", {"profile": profile, "settings": prof, "results": results, "timings": timings})
    print("\n".join(lines), flush=True)


def findings(textures, results, split_names=(("val", "validation"), ("test_offgrid", "off-grid test"))):
    """Statements about complexity (1 -> 3) and colour, from the measured MAEs."""
    out = []
    for split, name in split_names:
        mae = {t: results[t][split]["mae"] for t in textures if split in results[t]}
        for ver in ("bw", "color"):
            seq = [mae.get(f"Texture_{lvl}_{ver}") for lvl in (1, 2, 3)]
            if None in seq:
                continue
            falls = seq[0] > seq[1] > seq[2]
            out.append(f"- {name}, {ver}: MAE {seq[0]:.3f} -> {seq[1]:.3f} -> {seq[2]:.3f} from Texture 1 to 3: "
                       + ("falls monotonically, as in the paper." if falls else
                          "does NOT fall monotonically (the paper: it does)."))
        for lvl in (1, 2, 3):
            b, c = mae.get(f"Texture_{lvl}_bw"), mae.get(f"Texture_{lvl}_color")
            if b is None or c is None:
                continue
            out.append(f"- {name}, Texture {lvl}: colour {c:.3f} vs bw {b:.3f}: colour "
                       + ("helps" if c < b else "does not help") + ".")
    out.append("- The paper: validation error falls from Texture 1 to 3 for both versions; colour beats bw on "
               "validation at every level; on its test set colour loses at level 1 (1.32 vs 1.052) and wins "
               "at levels 2 and 3.")
    return out
