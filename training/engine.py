"""Named stages: train_one_epoch, predict, evaluate, and report writing."""
import csv
import time
from pathlib import Path

import numpy as np
import torch

from . import metrics as M
from . import plots
from .data import prepare_batch
from .losses import abs_err, pose_loss

SPLITS = ("val", "test", "test_offgrid")


def train_one_epoch(model, optimizer, scheduler, data, params, args, device, g, epoch, should_stop=None,
                    batches=None):
    """One pass over `data` (PoseSet), or until should_stop() is true; returns (mean loss, mean |error| deg).

    batches: this process's (images, labels) batches when several share the epoch (distributed.py);
    default: all of `data`, shuffled with g, which also draws the augmentation."""
    from tqdm import tqdm
    model.train()
    augment = {"photometric": args.photometric, "geometric": args.geometric, "gray": args.gray}
    tot_loss = tot_err = n = 0.0
    if batches is None:
        batches = data.batches(args.batch_size, shuffle=True, generator=g, drop_last=True)
        steps = (len(data) + args.batch_size - 1) // args.batch_size
    else:
        steps = len(batches)
    bar = tqdm(batches, total=steps, desc=f"epoch {epoch + 1}/{args.epochs}", unit="batch",
               disable=not args.progress, leave=False)
    for images, labels in bar:
        x = prepare_batch(images, params, augment, g).to(device, non_blocking=True)
        y = labels.to(device)
        out = model(x)
        loss = pose_loss(out, y, args.loss, args.delta, args.rotmat_weight)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if args.clip_grad:
            torch.nn.utils.clip_grad_norm_(model.parameters(), args.clip_grad)
        optimizer.step()
        scheduler.step()
        b = len(y)
        tot_loss += float(loss.detach()) * b
        tot_err += float(abs_err(out["euler_deg"].detach(), y).mean()) * b
        n += b
        bar.set_postfix(loss=f"{tot_loss / n:.3f}", mae=f"{tot_err / n:.3f}")
        if should_stop is not None and should_stop():
            break
    return tot_loss / max(n, 1), tot_err / max(n, 1)


@torch.no_grad()
def predict(model, data, params, device, batch_size=64):
    """(pred euler [N, 3], pred R [N, 3, 3] or None) as numpy for a PoseSet."""
    model.eval()
    eul, rot = [], []
    for images, _ in data.batches(batch_size):
        out = model(prepare_batch(images, params).to(device))
        eul.append(out["euler_deg"].float().cpu())
        if "rotmat" in out:
            rot.append(out["rotmat"].float().cpu())
    return torch.cat(eul).numpy(), (torch.cat(rot).numpy() if rot else None)


def evaluate(model, data, params, device, batch_size=64):
    """Metrics dict (metrics.compute) plus predictions for a PoseSet."""
    pred, R = predict(model, data, params, device, batch_size)
    return M.compute(pred, data.labels.numpy(), R), pred


def write_split_report(out_dir, split, names, true, pred, m, label=""):
    """metrics_<split>.json, predictions_<split>.csv and the split's figures."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    M.save_json(out_dir / f"metrics_{split}.json", m)
    with open(out_dir / f"predictions_{split}.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["file", "true_x", "true_y", "true_z", "pred_x", "pred_y", "pred_z"])
        for n_, t, p in zip(names, true, pred):
            w.writerow([n_, *(f"{v:.3f}" for v in t), *(f"{v:.4f}" for v in p)])
    return plots.split_figures(pred, true, out_dir, split, label)


def write_tables(out_dir, results, label, extra=""):
    """tables.md + metrics.json for {split: metrics}; returns the markdown."""
    rows = [(s, results[s]) for s in SPLITS if s in results]
    md = (f"# {label}: errors in degrees\n\n"
          "Err/Std/MAE/RMSE as in the paper (conventions.md); Max per axis; geodesic angle of "
          "R_pred^T R_true (mean, median, 95th percentile).\n\n" + M.table(rows) + "\n" + extra)
    (Path(out_dir) / "tables.md").write_text(md)
    M.save_json(Path(out_dir) / "metrics.json", results)
    return md


class CsvLog:
    """Per-epoch CSV log, appended (so a resumed run continues it)."""
    FIELDS = ["epoch", "lr", "train_loss", "train_mae", "val_mae", "val_rmse", "val_geodesic_mean",
              "epoch_s", "wall_s"]

    def __init__(self, path):
        self.path = Path(path)
        if not self.path.exists():
            with open(self.path, "w", newline="") as f:
                csv.writer(f).writerow(self.FIELDS)

    def write(self, **row):
        with open(self.path, "a", newline="") as f:
            csv.writer(f).writerow([row.get(k, "") for k in self.FIELDS])


class Timer:
    def __init__(self):
        self.t0 = time.time()

    def __call__(self):
        return time.time() - self.t0


def set_seed(seed):
    torch.manual_seed(seed)
    np.random.seed(seed % (2 ** 32))
