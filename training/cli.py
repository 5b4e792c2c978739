"""posetrain: train, evaluate, export and study MobileNet pose regressors.

    posetrain train  --data DIR --out DIR [...]      # DIR/train, DIR/val, [DIR/test, DIR/test_offgrid]
    posetrain eval   --model best.pth|model.onnx --data DIR --out DIR
    posetrain export --checkpoint best.pth --out model.onnx [--data DIR]
    posetrain study  --profile quick|p1 --out DIR

Defaults follow the paper's protocol P1 (MobileNetV2, 20 epochs, AdamW 5e-4,
cosine annealing, MAE + pseudo-Huber with delta = 1 deg, no augmentation).
"""
import argparse
import sys
from pathlib import Path

import numpy as np

from sim.engine_ray import EngineError

from . import metrics as M
from . import preprocess as pp
from .data import DatasetError
from .engine import SPLITS, write_split_report, write_tables
from .export import ExportMismatch, export_onnx, onnx_session, read_metadata, run_onnx
from .models import ARCHS
from .train import (add_common_arguments, add_train_arguments, check_images, load_checkpoint, load_split,
                    metrics_summary, pick_device, report_splits, set_threads, train)


class _Formatter(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
    def _get_help_string(self, action):
        if action.default is None:  # the help text says what happens
            return action.help
        return super()._get_help_string(action)


def get_args_parser():
    parser = argparse.ArgumentParser(prog="posetrain", description=__doc__, formatter_class=_Formatter)
    sub = parser.add_subparsers(dest="command", metavar="{train,eval,export,study}")
    sub.required = True

    t = sub.add_parser("train", help="train a model", formatter_class=_Formatter,
                       description="Train, evaluate and export one model.\n\nUnder torchrun (torchrun --nproc-per-node N "
                                   "--no-python posetrain train ...)\nthe processes share each step's --batch-size "
                                   "(DistributedDataParallel;\ngloo on CPU, NCCL on GPUs) and rank 0 writes every "
                                   "file (docs/cluster.md).")
    add_train_arguments(t)
    add_common_arguments(t)

    e = sub.add_parser("eval", help="evaluate a checkpoint or ONNX model", formatter_class=_Formatter)
    e.add_argument("--model", required=True, help="checkpoint (.pth) or ONNX model (.onnx)")
    e.add_argument("--data", required=True, help="dataset folder with split subfolders")
    e.add_argument("--splits", nargs="*", default=list(SPLITS), help="splits to evaluate (missing ones skipped)")
    e.add_argument("--out", required=True, help="output folder for tables, metrics JSON and figures")
    e.add_argument("--label", default=None, help="title for the tables (default: the model's texture)")
    add_common_arguments(e)

    x = sub.add_parser("export", help="export a checkpoint to ONNX (checked with onnxruntime)",
                       formatter_class=_Formatter)
    x.add_argument("--checkpoint", required=True, help="checkpoint (.pth)")
    x.add_argument("--out", required=True, help="ONNX file to write")
    x.add_argument("--data", default=None, help="dataset folder: check on its val frames (else random inputs)")
    x.add_argument("--tol", type=float, default=1e-4, help="max |ONNX - PyTorch| in degrees")
    add_common_arguments(x)

    s = sub.add_parser("study", help="the paper's six-texture study", formatter_class=_Formatter)
    s.add_argument("--profile", default="quick", help="quick (2-core CPU, < 1 h), p1 (the paper's protocol) or smoke (plumbing check)")
    s.add_argument("--out", required=True, help="study folder (datasets, runs, report.md)")
    s.add_argument("--textures", nargs="*", default=None, help="subset of texture names (default: all six)")
    s.add_argument("--texture-dir", default=None, help="folder of Texture_*.png (default: OUT/textures, generated)")
    s.add_argument("--arch", default=None, choices=ARCHS, help="override the profile's network")
    s.add_argument("--epochs", type=int, default=None, help="override the profile's epochs")
    s.add_argument("--seed", type=int, default=0, help="seed for datasets and training")
    s.add_argument("--engine", default="local", choices=("local", "ray"),
                   help="local: the runs one after another here; ray: each run a Ray task (docs/cluster.md)")
    s.add_argument("--ray-address", default=None,
                   help="with --engine ray: the cluster to join (default: RAY_ADDRESS, else a local Ray instance)")
    s.add_argument("--run-cpus", type=int, default=1,
                   help="with --engine ray: CPUs per run (its threads and worker processes); a run on CUDA "
                        "also takes one GPU")
    add_common_arguments(s)
    return parser


# ------------------------------------------------------------------------ eval

def evaluate_cmd(args):
    set_threads(args.threads)
    device = pick_device(args.device)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if str(args.model).endswith(".onnx"):
        meta = read_metadata(args.model)
        if "spherepose.preprocess" not in meta:
            raise SystemExit(f"posetrain: {args.model}: missing metadata key spherepose.preprocess")
        try:
            params = pp.params(meta["spherepose.preprocess"], model=args.model)
        except ValueError as e:
            raise SystemExit(f"posetrain: {e}") from None
        label = args.label or meta.get("spherepose.texture", Path(args.model).stem)
        from .data import prepare_batch
        results = {}
        sess = onnx_session(args.model, threads=args.threads or None)
        for split in args.splits:
            ds = load_split(args.data, split, params, args, False)
            if ds is None:
                continue
            preds, rots = [], []
            for images, _ in ds.batches(64):
                o = run_onnx(sess, prepare_batch(images, params).numpy())
                preds.append(o["euler_deg"])
                if "rotmat" in o:
                    rots.append(o["rotmat"])
            pred = np.concatenate(preds)
            m = M.compute(pred, ds.labels.numpy(), np.concatenate(rots) if rots else None)
            write_split_report(out, split, ds.names, ds.labels.numpy(), pred, m, label)
            results[split] = m
        print(write_tables(out, results, label))
        return results
    model, ck = load_checkpoint(args.model, device)
    return report_splits(model, ck["config"], args.data, args.splits, out, args, device,
                         label=args.label or ck["config"].get("texture", "model"))


# ---------------------------------------------------------------------- export

def export_cmd(args):
    set_threads(args.threads)
    model, ck = load_checkpoint(args.checkpoint, "cpu")
    x = None
    if args.data:
        ds = load_split(args.data, "val", ck["config"]["preprocess"], args, True)
        x = check_images(ds, ck["config"]["preprocess"])
    diff = export_onnx(model, ck["config"], args.out, metrics_summary(ck.get("val_metrics")), x, args.tol)
    print(f"posetrain: wrote {args.out} (onnxruntime vs PyTorch max diff {diff:.2g} deg)")


def main(argv=None):
    args = get_args_parser().parse_args(argv)
    try:
        if args.command == "train":
            train(args)
        elif args.command == "eval":
            evaluate_cmd(args)
        elif args.command == "export":
            export_cmd(args)
        elif args.command == "study":
            from .study import run_study
            run_study(args)
    except (DatasetError, ExportMismatch, pp.NoSphere, ValueError) as e:
        print(f"posetrain: error: {e}", file=sys.stderr)
        return 2
    except EngineError as e:    # the cluster, not the arguments
        print(f"posetrain: error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
