"""Refinement and confidence of a model on labelled frame folders, through poseinfer.

For each folder (frames named <x>_<y>_<z>.png, as `sim dataset` and `python -m bench.raycast`
write them): the network's and the refined errors (mean over frames and axes of |wrapped
difference|, and the largest on one axis), the share of frames flagged (not confident) and why,
the residuals, and refinement's time beside the network's (CPU when poseinfer runs alone; the
`refine_ms` and `infer_ms` it prints). A markdown table on stdout (docs/refine.md has the
readings):

    .venv/bin/python bench/refine_eval.py --model training/models/Texture_3_color.onnx DIR...
    .venv/bin/python bench/refine_eval.py --model M --no-refine DIR...
"""
import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sim.names import parse_name  # noqa: E402


def wrap(a):
    return (np.asarray(a, np.float64) + 180.0) % 360.0 - 180.0


def run_folder(exe, model, folder, extra):
    files = sorted(str(p) for p in Path(folder).iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
    if not files:
        raise SystemExit(f"refine_eval: {folder}: no frames")
    proc = subprocess.run([str(exe), "--model", str(model), "--timings", *extra, *files],
                          capture_output=True, text=True)
    if proc.returncode not in (0, 1):
        raise SystemExit(f"refine_eval: poseinfer failed: {proc.stderr.strip()}")
    rows = [json.loads(line) for line in proc.stdout.splitlines()]
    ok = [r for r in rows if "error" not in r]
    truth = np.array([parse_name(r["file"]) for r in ok], np.float64)
    est = np.array([[r["x"], r["y"], r["z"]] for r in ok])
    net = np.array([r["net"] for r in ok])
    e, en = np.abs(wrap(est - truth)), np.abs(wrap(net - truth))
    flagged = np.array([r["confident"] is not True for r in ok])
    notes = {}
    for r in ok:
        if r.get("note"):
            k = r["note"].split(" (")[0]
            notes[k] = notes.get(k, 0) + 1
    res = np.array([r["residual"] if r["residual"] is not None else np.nan for r in ok])
    return {"folder": str(folder), "n": len(rows), "failed": len(rows) - len(ok),
            "net_mae": float(en.mean()), "mae": float(e.mean()), "max": float(e.max()),
            "flagged": float(flagged.mean()), "notes": notes,
            "residual_median": float(np.nanmedian(res)), "residual_max": float(np.nanmax(res)),
            "refine_ms_p50": float(np.median([r["refine_ms"] for r in ok])),
            "infer_ms_p50": float(np.median([r["infer_ms"] for r in ok]))}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--model", required=True, help="ONNX model (with its texture for refinement)")
    ap.add_argument("--poseinfer", default=os.environ.get("POSEINFER", str(ROOT / "host" / "build" / "poseinfer")),
                    help="the poseinfer binary")
    ap.add_argument("--no-refine", action="store_true", help="judge the network's angles, unrefined")
    ap.add_argument("--json", action="store_true", help="one JSON object per folder instead of the table")
    ap.add_argument("folders", nargs="+", help="folders of labelled frames")
    args = ap.parse_args(argv)
    extra = ["--no-refine"] if args.no_refine else []
    out = [run_folder(args.poseinfer, args.model, f, extra) for f in args.folders]
    if args.json:
        for o in out:
            print(json.dumps(o))
        return 0
    print(f"model `{args.model}`{' --no-refine' if args.no_refine else ''}\n")
    print("| frames | n | failed | network MAE | refined MAE | max | flagged | notes | residual median / max |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | --- | ---: |")
    for o in out:
        notes = ", ".join(f"{k}: {v}" for k, v in o["notes"].items()) or "–"
        print(f"| {o['folder']} | {o['n']} | {o['failed']} | {o['net_mae']:.3f}° | {o['mae']:.3f}° | {o['max']:.2f}° | "
              f"{100 * o['flagged']:.1f} % | {notes} | {o['residual_median']:.4f} / {o['residual_max']:.4f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
