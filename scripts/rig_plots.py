#!/usr/bin/env python3
"""PNG plots of a poserig run from its poses.csv, drawn with the trainer's figures.

usage: rig_plots.py OUT_DIR   (reads OUT_DIR/poses.csv, writes OUT_DIR/rig_*.png)
"""
import argparse
import csv
import sys
from pathlib import Path

import numpy as np

from training import plots


def load(path):
    """Commanded and estimated poses (degrees) of the measured rows of poses.csv."""
    cmd, est = [], []
    with open(path, newline="") as f:
        for lineno, row in enumerate(csv.DictReader(f), start=2):
            if row.get("status") != "ok":
                continue
            try:
                cmd.append([float(row[f"cmd_{a}"]) for a in "xyz"])
                est.append([float(row[f"est_{a}"]) for a in "xyz"])
            except (KeyError, ValueError) as e:
                raise SystemExit(f"{path}:{lineno}: bad row ({e})")
    return np.array(cmd).reshape(-1, 3), np.array(est).reshape(-1, 3)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out_dir", type=Path, help="poserig output folder holding poses.csv")
    args = p.parse_args(argv)
    cmd, est = load(args.out_dir / "poses.csv")
    if len(cmd) == 0:
        print(f"{args.out_dir / 'poses.csv'}: no measured pose to plot", file=sys.stderr)
        return 1
    plots.box(est, cmd, args.out_dir / "rig_box.png", title="rig: |error| per axis (Fig. 6)")
    plots.test_panels(est, cmd, args.out_dir / "rig_panels.png",
                      title="rig: commanded vs estimated, error line, error histogram (Fig. 4)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
