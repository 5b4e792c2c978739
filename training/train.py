"""One training run (`posetrain train`), called with arguments by the command
line (cli.py) and by the study (study.py):

    train(options("DATA", "OUT", arch="mobilenet_v2", epochs=20))

The options are the command line's, with the same names and defaults: this
module defines them (add_train_arguments, add_common_arguments), so the two
callers cannot drift apart. Also here: the pieces `posetrain eval` and
`posetrain export` share with a run (devices, checkpoints, split reports).
"""
import argparse
import datetime
import json
import os
import platform
import sys
from pathlib import Path

import numpy as np
import torch

from . import distributed
from . import metrics as M
from . import preprocess as pp
from .data import PoseSet, check_label_ranges
from .engine import SPLITS, CsvLog, Timer, evaluate, set_seed, train_one_epoch, write_split_report, write_tables
from .export import export_onnx
from .losses import LOSSES
from .models import ARCHS, HEADS, build


# --------------------------------------------------------------------- options

def add_common_arguments(p):
    """Options of every posetrain command that loads frames or runs a model."""
    p.add_argument("--device", default="auto", help="auto (cuda when present, else cpu), cpu, cuda, cuda:N")
    p.add_argument("--threads", type=int, default=0, help="torch CPU threads (0 = all cores)")
    p.add_argument("--no-cache", dest="cache", action="store_false",
                   help="do not read or write the per-folder preprocessed-crop cache")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bars")
    p.add_argument("--workers", type=int, default=0,
                   help="processes preprocessing frames into the cache (0 = every core)")


def add_train_arguments(t):
    """The options of one training run (posetrain train; also add_common_arguments)."""
    t.add_argument("--data", required=True, help="dataset folder (sim dataset) with train/ and val/ (test/, test_offgrid/ optional)")
    t.add_argument("--extra-train", action="append", default=[], metavar="DIR",
                   help="more training split folders (repeatable), e.g. continuous or randomised poses")
    t.add_argument("--out", required=True, help="output folder (checkpoints, log.csv, report, model.onnx)")
    t.add_argument("--texture", default=None, help="texture name for the report and metadata "
                   "(default: from the dataset record, else the folder name)")
    t.add_argument("--arch", default="mobilenet_v2", choices=ARCHS, help="network")
    t.add_argument("--head", default="euler", choices=HEADS, help="output head")
    t.add_argument("--width-mult", type=float, default=1.0, help="MobileNet width multiplier")
    t.add_argument("--dropout", type=float, default=0.0, help="dropout before the last layer")
    t.add_argument("--epochs", type=int, default=None,
                   help="epochs (default: 20; with --resume: the checkpoint's, or more to extend the run)")
    t.add_argument("--batch-size", "-b", type=int, default=32, help="batch size")
    t.add_argument("--lr", type=float, default=5e-4, help="AdamW learning rate (cosine-annealed per step to 0)")
    t.add_argument("--weight-decay", type=float, default=0.01, help="AdamW weight decay")
    t.add_argument("--warmup-steps", type=int, default=0, help="linear warm-up steps before the cosine")
    t.add_argument("--time-budget", type=float, default=0.0,
                   help="minutes of training: the cosine runs over wall time instead of steps and training "
                        "stops when it is spent (--epochs is then an upper bound); 0 = off")
    t.add_argument("--loss", default="mae+phuber", choices=LOSSES, help="loss on wrapped Euler differences")
    t.add_argument("--delta", type=float, default=1.0, help="pseudo-Huber delta, degrees")
    t.add_argument("--rotmat-weight", type=float, default=1.0,
                   help="rot6d head: weight of the matrix-element L1 term (see losses.py)")
    t.add_argument("--clip-grad", type=float, default=0.0, help="gradient-norm clip (0 = off)")
    t.add_argument("--photometric", type=float, default=0.0,
                   help="photometric augmentation strength (0 = off, 1 = light/contrast/gamma/blur/noise)")
    t.add_argument("--geometric", action="store_true", help="small crop-jitter augmentation (shift/scale)")
    t.add_argument("--gray", type=float, default=0.0,
                   help="probability of training a crop as a mono camera sees it (its luma in all three "
                        "channels; 0 = off)")
    t.add_argument("--size", type=int, default=None, help="network input size (default: preprocessing's 128)")
    t.add_argument("--preprocess", default=None, help="JSON overrides of the sphere-crop-v1 parameters")
    t.add_argument("--seed", type=int, default=0, help="random seed")
    t.add_argument("--resume", default=None, help="checkpoint to resume from (its args are reused)")
    t.add_argument("--init", default=None,
                   help="start from this checkpoint's (.pth) or exported model's (.onnx) weights (fine-tuning: "
                        "new optimiser and schedule; architecture and head must match, and a checkpoint's "
                        "preprocessing too)")
    t.add_argument("--export-tol", type=float, default=1e-4,
                   help="max |onnxruntime - PyTorch| in degrees at export")
    t.add_argument("--no-export", dest="export", action="store_false", help="skip ONNX export at the end")
    t.add_argument("--eval-splits", nargs="*", default=list(SPLITS), help="splits evaluated at the end")
    t.add_argument("--strict", action="store_true",
                   help="refuse frames labelled outside the model's ranges (without it: a warning names them)")


def options(data, out, **kw):
    """A run's options: the command line's defaults, then kw (names as in the
    namespace, e.g. batch_size=32). An unknown name is a TypeError."""
    p = argparse.ArgumentParser(prog="posetrain train")
    add_train_arguments(p)
    add_common_arguments(p)
    args = p.parse_args(["--data", str(data), "--out", str(out)])
    args.command = "train"  # as on the command line, so a checkpoint's saved args are the same
    for k, v in kw.items():
        if not hasattr(args, k):
            raise TypeError(f"train options: unknown option {k!r}")
        setattr(args, k, v)
    return args


# --------------------------------------------------------------------- helpers

def pick_device(name):
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        d = torch.device(name)
    except RuntimeError:
        raise SystemExit(f"posetrain: unknown device {name!r}; valid: auto, cpu, cuda, cuda:N") from None
    if d.type == "cuda" and not torch.cuda.is_available():
        raise SystemExit(f"posetrain: device {name!r} requested but CUDA is not available; valid here: auto, cpu")
    return d


def set_threads(n):
    torch.set_num_threads(n if n > 0 else (os.cpu_count() or 1))


def dataset_record(data_dir):
    """The dataset folder's record (first *.json with a 'texture' or 'command' key), or {}."""
    for p in sorted(Path(data_dir).glob("*.json")):
        try:
            d = json.loads(p.read_text())
        except (OSError, ValueError):
            continue
        if isinstance(d, dict) and ("texture" in d or "command" in d or "seed" in d):
            d["_file"] = p.name
            return d
    return {}


def texture_name(data_dir, record, given=None):
    if given:
        return given
    t = record.get("texture")
    if isinstance(t, dict):
        t = t.get("name") or t.get("path")
    if t:
        return Path(str(t)).stem
    return Path(data_dir).resolve().name


def load_checkpoint(path, device="cpu"):
    ck = torch.load(path, map_location=device, weights_only=False)
    if not isinstance(ck, dict) or "model" not in ck or "config" not in ck:
        raise SystemExit(f"posetrain: {path}: not a posetrain checkpoint")
    model = build(ck["config"])
    model.load_state_dict(ck["model"])
    return model.to(device).eval(), ck


def load_split(root, split, params, args, required):
    d = Path(root) / split
    if not d.exists():
        if required:
            raise SystemExit(f"posetrain: {d}: split folder missing")
        return None
    return PoseSet(d, params, cache=args.cache, progress=args.progress, workers=args.workers)



# ----------------------------------------------------------------------- train

def train(args):
    """One run; under torchrun (WORLD_SIZE > 1) this process's part of it (training/distributed.py)."""
    try:
        return _train(args)
    finally:
        distributed.finish(distributed.from_env())


def _train(args):
    timer = Timer()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    start_epoch, ck = 0, None
    if args.resume:
        ck = torch.load(args.resume, map_location="cpu", weights_only=False)
        keep = {k: getattr(args, k) for k in ("resume", "device", "threads", "progress", "out", "export")}
        epochs = args.epochs
        vars(args).update(ck["args"])
        vars(args).update(keep)
        args.epochs = epochs or args.epochs
        start_epoch = ck["epoch"] + 1
    args.epochs = args.epochs or 20
    ctx = distributed.from_env()
    if ctx.active:
        ctx, device = distributed.setup(args.device, args.batch_size)
        torch.set_num_threads(distributed.threads(args.threads, ctx))
        args.progress = args.progress and ctx.main
    else:
        set_threads(args.threads)
    set_seed(args.seed)
    if not ctx.active:
        device = pick_device(args.device)
    params = pp.params(args.preprocess)
    if args.size:
        params["size"] = args.size
    record = dataset_record(args.data)
    config = {"arch": args.arch, "head": args.head, "width_mult": args.width_mult, "dropout": args.dropout,
              "angle_scale": 30.0, "preprocess": params,
              "ranges": {"x": [-30, 30], "y": [-30, 30], "z": [-30, 30]},
              "texture": texture_name(args.data, record, args.texture), "dataset_record": record}
    if ck is not None:
        config = ck["config"]
        params = config["preprocess"]

    with distributed.main_first(ctx):   # one process at a time builds a folder's crop cache
        train_set = load_split(args.data, "train", params, args, True)
        for extra in args.extra_train:
            more = PoseSet(extra, params, cache=args.cache, progress=args.progress, workers=args.workers)
            train_set.images = torch.cat([train_set.images, more.images])
            train_set.labels = torch.cat([train_set.labels, more.labels])
            train_set.names = train_set.names + [f"{Path(extra).name}/{n}" for n in more.names]
        val_set = load_split(args.data, "val", params, args, True)
    for split_set in (train_set, val_set):  # frames labelled outside the model's ranges: named, or refused
        check_label_ranges(split_set, config["ranges"], strict=getattr(args, "strict", False))
    if ctx.main:
        print(f"posetrain: {config['texture']}: {len(train_set)} train, {len(val_set)} val frames; "
              f"{args.arch}/{args.head} on {device} ({torch.get_num_threads()} threads)"
              + (f" x {ctx.world} processes, batch {args.batch_size // ctx.world} each" if ctx.active else ""),
              flush=True)

    model = build(config).to(device)
    optimizer = torch.optim.AdamW(model.parameters(), lr=args.lr, weight_decay=args.weight_decay)
    steps_per_epoch = len(train_set) // args.batch_size if len(train_set) >= args.batch_size else 1
    total = max(1, args.epochs * steps_per_epoch)
    warm = max(0, args.warmup_steps)

    budget_s = 60.0 * args.time_budget
    spent0 = ck.get("train_s", 0.0) if ck is not None else 0.0
    train_clock = Timer()

    def spent():
        return spent0 + train_clock()

    def lr_at(step):  # linear warm-up, then cosine annealing to 0 over the remaining steps (or time)
        if step < warm:
            return (step + 1) / warm
        frac = (step - warm) / max(1, total - warm)
        if budget_s > 0:
            frac = spent() / budget_s
        return 0.5 * (1 + np.cos(np.pi * min(1.0, frac)))
    scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, lr_at)
    g = torch.Generator().manual_seed(args.seed)
    best_mae = float("inf")
    if args.init and ck is None and str(args.init).endswith(".onnx"):
        # an exported model: its folded BatchNorms are unfolded on this run's own crops
        from .data import normalise
        from .onnx_init import load_onnx_weights
        calib = normalise(train_set.images[:256], params).to(device)
        load_onnx_weights(model, args.init, calib)
        print(f"posetrain: weights from {args.init}", flush=True)
    elif args.init and ck is None:
        init = torch.load(args.init, map_location="cpu", weights_only=False)
        for k in ("arch", "head", "preprocess"):
            if init["config"].get(k) != config.get(k):
                raise ValueError(f"{args.init}: {k} {init['config'].get(k)!r} does not match this run's "
                                 f"{config.get(k)!r}")
        model.load_state_dict(init["model"])
        print(f"posetrain: weights from {args.init}", flush=True)
    if ck is not None:
        model.load_state_dict(ck["model"])
        optimizer.load_state_dict(ck["optimizer"])
        scheduler.load_state_dict(ck["scheduler"])
        g.set_state(ck["generator"])
        best_mae = ck.get("best_mae", best_mae)
        if ctx.main:
            print(f"posetrain: resumed from {args.resume} at epoch {start_epoch + 1}", flush=True)
    train_model = distributed.wrap(model, ctx, device) if ctx.active else model   # after the weights are loaded
    log = CsvLog(out / "log.csv") if ctx.main else None
    saved_args = {k: v for k, v in vars(args).items() if k != "func"}
    for epoch in range(start_epoch, args.epochs):
        t_ep = Timer()
        stop = (lambda: distributed.agree(spent() >= budget_s, ctx)) if budget_s > 0 else None
        if ctx.active:
            loss, tr_mae = train_one_epoch(train_model, optimizer, scheduler, train_set, params, args, device,
                                           distributed.generator(args.seed, ctx, epoch), epoch, stop,
                                           distributed.ShardBatches(train_set, args.batch_size, ctx, args.seed, epoch))
            loss, tr_mae = distributed.average([loss, tr_mae], ctx)
        else:
            loss, tr_mae = train_one_epoch(model, optimizer, scheduler, train_set, params, args, device, g, epoch, stop)
        if not ctx.main:    # rank 0 alone evaluates and writes; this process waits for it at the next step
            if budget_s > 0 and distributed.agree(spent() >= budget_s, ctx):
                break
            continue
        vm, _ = evaluate(model, val_set, params, device)
        lr = optimizer.param_groups[0]["lr"]
        log.write(epoch=epoch + 1, lr=f"{lr:.3g}", train_loss=f"{loss:.4f}", train_mae=f"{tr_mae:.4f}",
                  val_mae=f"{vm['mae']:.4f}", val_rmse=f"{vm['rmse']:.4f}",
                  val_geodesic_mean=f"{vm['geodesic_mean']:.4f}", epoch_s=f"{t_ep():.1f}", wall_s=f"{timer():.1f}")
        print(f"epoch {epoch + 1}/{args.epochs}: loss {loss:.4f} train MAE {tr_mae:.3f} | val MAE {vm['mae']:.3f} "
              f"RMSE {vm['rmse']:.3f} geo {vm['geodesic_mean']:.3f} deg | {t_ep():.0f} s", flush=True)
        state = {"model": model.state_dict(), "optimizer": optimizer.state_dict(),
                 "scheduler": scheduler.state_dict(), "generator": g.get_state(), "epoch": epoch,
                 "args": saved_args, "config": config, "val_metrics": vm,
                 "best_mae": min(best_mae, vm["mae"]), "train_s": spent()}
        if vm["mae"] < best_mae:
            best_mae = vm["mae"]
            torch.save(state, out / "best.pth.tmp")
            os.replace(out / "best.pth.tmp", out / "best.pth")
        torch.save(state, out / "checkpoint.pth.tmp")
        os.replace(out / "checkpoint.pth.tmp", out / "checkpoint.pth")
        if budget_s > 0 and distributed.agree(spent() >= budget_s, ctx):
            print(f"posetrain: time budget of {args.time_budget:g} min spent after epoch {epoch + 1}", flush=True)
            break
    train_s = timer()
    if not ctx.main:
        return None

    # final report on the best checkpoint
    model, ck = load_checkpoint(out / "best.pth", device)
    results = report_splits(model, ck["config"], args.data, args.eval_splits, out, args, device,
                            label=config["texture"], sets={"val": val_set})
    info = {"texture": config["texture"], "epochs": ck_last_epoch(out), "best_epoch": ck["epoch"] + 1,
            "train_frames": len(train_set), "train_s": round(train_s, 1), "device": describe_device(device),
            "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
            "command": "posetrain " + " ".join(sys.argv[1:]) if sys.argv[0].endswith("posetrain") else None}
    if ctx.active:
        info["processes"] = ctx.world
    M.save_json(out / "run.json", info)
    if args.export:
        val_x = check_images(val_set, params)
        diff = export_onnx(model, ck["config"], out / "model.onnx", metrics_summary(results.get("val")), val_x,
                           getattr(args, "export_tol", 1e-4))
        print(f"posetrain: wrote {out / 'model.onnx'} (onnxruntime vs PyTorch max diff {diff:.2g} deg)")
        info["export_max_diff_deg"] = diff
        M.save_json(out / "run.json", info)
    return results


def ck_last_epoch(out):
    """Epochs completed, from the log."""
    import csv
    with open(Path(out) / "log.csv") as f:
        rows = list(csv.DictReader(f))
    return int(rows[-1]["epoch"]) if rows else 0


def describe_device(device):
    if device.type == "cuda":
        return torch.cuda.get_device_name(device)
    name = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            name = next((l.split(":", 1)[1].strip() for l in f if l.startswith("model name")), name)
    except OSError:
        pass
    return f"CPU {name} ({os.cpu_count()} cores), {torch.get_num_threads()} threads"


def metrics_summary(m):
    """The validation metrics stored in the ONNX metadata."""
    if not m:
        return {}
    keys = ("n", "err", "std", "mae", "rmse", "max", "geodesic_mean", "geodesic_median", "geodesic_p95")
    return {k: m[k] for k in keys if k in m}


def check_images(data, params, n=16):
    from .data import prepare_batch
    return prepare_batch(data.images[:n], params).numpy()


def report_splits(model, config, data_dir, splits, out, args, device, label, sets=None):
    """Evaluate a PyTorch model on the splits present; write tables, JSON and figures."""
    params = config["preprocess"]
    results = {}
    for split in splits:
        ds = (sets or {}).get(split) or load_split(data_dir, split, params, args, False)
        if ds is None:
            continue
        m, pred = evaluate(model, ds, params, device)
        write_split_report(out, split, ds.names, ds.labels.numpy(), pred, m, label)
        results[split] = m
    md = write_tables(out, results, label)
    print(md, flush=True)
    return results

