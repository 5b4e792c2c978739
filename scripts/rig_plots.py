#!/usr/bin/env python3
"""PNG plots of a poserig run from its poses.csv, drawn with the trainer's figures.

usage: rig_plots.py OUT_DIR   (reads OUT_DIR/poses.csv, writes OUT_DIR/rig_*.png)

rig_box.png and rig_panels.png show the confident poses, as poserig's summary
does (all measured poses when the model judges none, or when it flagged them
all); rig_poses.png shows every measured pose's error, flagged ones as red
crosses. A poses.csv without the `confident` column (an older run) counts
every pose as confident.
"""
import argparse
import csv
import sys
from pathlib import Path

import numpy as np

from training import plots
from matplotlib.ticker import MaxNLocator  # after training.plots, which picks the Agg backend


def load(path):
    """Commanded and estimated poses (degrees), pose indices and flagged mask of the measured
    rows of poses.csv."""
    cmd, est, index, flagged = [], [], [], []
    with open(path, newline="") as f:
        for lineno, row in enumerate(csv.DictReader(f), start=2):
            if row.get("status") != "ok":
                continue
            conf = row.get("confident") or ""
            if conf not in ("", "true", "false"):
                raise SystemExit(f"{path}:{lineno}: bad row (confident is {conf!r}, not true, false or empty)")
            try:
                cmd.append([float(row[f"cmd_{a}"]) for a in "xyz"])
                est.append([float(row[f"est_{a}"]) for a in "xyz"])
                index.append(int(row["index"]))
            except (KeyError, TypeError, ValueError) as e:
                raise SystemExit(f"{path}:{lineno}: bad row ({e})")
            flagged.append(conf == "false")
    return (np.array(cmd).reshape(-1, 3), np.array(est).reshape(-1, 3), np.array(index, int),
            np.array(flagged, bool))


def poses_figure(cmd, est, index, flagged, path):
    """|error| per axis against the pose's index: confident poses as dots, flagged as red crosses."""
    plt = plots.plt
    e = np.abs(plots.wrap_deg(est - cmd))
    fig, axs = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    for a, ax in enumerate(axs):
        ax.plot(index[~flagged], e[~flagged, a], "o", ms=3, color=plots.COLOURS[a], label="confident")
        if flagged.any():
            ax.plot(index[flagged], e[flagged, a], "x", ms=6, color="red", label="flagged")
        ax.set_ylabel(f"|error| {plots.AXES[a]} (°)")
        if e[:, a].max() > 0 and e[:, a].max() > 20 * max(np.median(e[:, a]), 1e-3):
            ax.set_yscale("log")       # a few flagged poses far off would flatten the rest
    axs[0].legend(loc="best", fontsize=8, framealpha=0.5)
    axs[-1].set_xlabel("pose (index in the plan)")
    axs[-1].xaxis.set_major_locator(MaxNLocator(integer=True))
    fig.suptitle(f"rig: |error| per pose ({int(flagged.sum())} of {len(flagged)} flagged)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out_dir", type=Path, help="poserig output folder holding poses.csv")
    args = p.parse_args(argv)
    cmd, est, index, flagged = load(args.out_dir / "poses.csv")
    if len(cmd) == 0:
        print(f"{args.out_dir / 'poses.csv'}: no measured pose to plot", file=sys.stderr)
        return 1
    n, k = len(cmd), int(flagged.sum())
    if k == 0:
        sel, which = slice(None), f"{n} poses"
    elif k < n:
        sel, which = ~flagged, f"{n - k} confident poses, {k} flagged left out"
    else:
        sel, which = slice(None), f"all {n} poses flagged"
    plots.box(est[sel], cmd[sel], args.out_dir / "rig_box.png", title=f"rig: |error| per axis (Fig. 6), {which}")
    plots.test_panels(est[sel], cmd[sel], args.out_dir / "rig_panels.png",
                      title=f"rig: commanded vs estimated, error line, error histogram (Fig. 4), {which}")
    poses_figure(cmd, est, index, flagged, args.out_dir / "rig_poses.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
