"""The paper's error metrics, exactly as docs/conventions.md defines them.

e_a = |wrap(pred_a - true_a)| per sample and axis a;
Err_a = mean e_a, Std_a = population std of e_a, RMSE_a = sqrt(mean e_a^2),
MAE = mean of e over samples and axes, RMSE = sqrt(mean e^2) over samples and axes,
Max_a = max e_a; plus the geodesic angle of R_pred^T R_true (mean, median, p95).
"""
import json
import math

import numpy as np

from sim.pose import euler_to_matrix, geodesic_deg, wrap_deg

AXES = ("X", "Y", "Z")


def abs_errors(pred_deg, true_deg):
    """[N, 3] |wrap(pred - true)| in degrees."""
    return np.abs(wrap_deg(np.asarray(pred_deg, float) - np.asarray(true_deg, float)))


def geodesic_errors(pred_deg, true_deg, pred_R=None):
    """[N] geodesic angle between predicted and true rotations, degrees."""
    out = []
    for i, t in enumerate(np.asarray(true_deg, float)):
        Rp = np.asarray(pred_R[i], float) if pred_R is not None else euler_to_matrix(*pred_deg[i])
        out.append(geodesic_deg(Rp, euler_to_matrix(*t)))
    return np.asarray(out)


def compute(pred_deg, true_deg, pred_R=None):
    """Metrics dict (plain floats/lists, JSON-ready) for predictions vs truth, degrees."""
    pred_deg = np.asarray(pred_deg, float)
    true_deg = np.asarray(true_deg, float)
    if pred_deg.shape != true_deg.shape or pred_deg.ndim != 2 or pred_deg.shape[1] != 3 or len(pred_deg) == 0:
        raise ValueError(f"need matching non-empty [N, 3] arrays, got {pred_deg.shape} and {true_deg.shape}")
    e = abs_errors(pred_deg, true_deg)
    g = geodesic_errors(pred_deg, true_deg, pred_R)
    return {
        "n": int(len(e)),
        "err": e.mean(0).tolist(),
        "std": e.std(0).tolist(),  # population std (ddof=0)
        "rmse_axis": np.sqrt((e ** 2).mean(0)).tolist(),
        "max": e.max(0).tolist(),
        "mae": float(e.mean()),
        "rmse": float(np.sqrt((e ** 2).mean())),
        "geodesic_mean": float(g.mean()),
        "geodesic_median": float(np.median(g)),
        "geodesic_p95": float(np.percentile(g, 95)),
    }


def from_err_std(err, std):
    """MAE and RMSE implied by per-axis Err and Std over equal sample counts
    (MAE = mean Err; RMSE^2 = mean(Err^2 + Std^2)): how the paper's rows relate."""
    err, std = np.asarray(err, float), np.asarray(std, float)
    return float(err.mean()), float(math.sqrt(((err ** 2) + (std ** 2)).mean()))


TABLE_HEADER = ("| {label} | Err_X | Err_Y | Err_Z | Std_X | Std_Y | Std_Z | MAE | RMSE "
                "| Max_X | Max_Y | Max_Z | geo mean | geo median | geo p95 | n |\n"
                "| --- |" + " ---: |" * 15)


def table_row(label, m, digits=3):
    """One markdown row in the paper's Table 1 column order, then Max, geodesic and n."""
    f = lambda v: f"{v:.{digits}f}"
    cells = [*map(f, m["err"]), *map(f, m["std"]), f(m["mae"]), f(m["rmse"]), *map(f, m["max"]),
             f(m["geodesic_mean"]), f(m["geodesic_median"]), f(m["geodesic_p95"]), str(m["n"])]
    return f"| {label} | " + " | ".join(cells) + " |"


def table(rows, label="split"):
    """Markdown table from [(label, metrics)]."""
    return "\n".join([TABLE_HEADER.format(label=label)] + [table_row(k, m) for k, m in rows])


def save_json(path, obj):
    with open(path, "w") as f:
        json.dump(obj, f, indent=2)
        f.write("\n")
