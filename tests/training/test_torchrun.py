"""`torchrun --nproc-per-node 2 --no-python posetrain train` (gloo on CPU) trains one epoch on a tiny
set; rank 0 leaves a checkpoint that loads, a model that exports, and the run's files once; the
checkpoint resumes in one process."""
import csv
import json
import os
import subprocess
import sys

import cv2
import numpy as np
import pytest

from training.cli import main
from training.export import read_metadata, run_onnx
from training.train import load_checkpoint

render = pytest.importorskip("sim.render")
from sim.camera import Camera  # noqa: E402
from sim.names import format_name  # noqa: E402

from test_train_export import _texture  # noqa: E402

BIN = os.path.dirname(sys.executable)


@pytest.fixture(scope="module")
def tiny_set(tmp_path_factory):
    root = tmp_path_factory.mktemp("tiny_ddp")
    r = render.Renderer(_texture(1), Camera(width=96, height=80, focal_mm=16.0 * 96 / 640))
    rng = np.random.default_rng(1)
    for split, n in (("train", 34), ("val", 8)):
        (root / split).mkdir()
        for pose in rng.uniform(-30, 30, (n, 3)).round(1):
            cv2.imwrite(str(root / split / format_name(*pose)), r.render(tuple(pose))[:, :, ::-1])
    r.close()
    (root / "dataset.json").write_text(json.dumps({"texture": "tiny_patches.png", "seed": 1}))
    return root


@pytest.mark.slow
def test_two_processes_train_one_epoch_and_rank_0_writes(tiny_set, tmp_path):
    out = tmp_path / "run"
    env = dict(os.environ, OMP_NUM_THREADS="1")
    r = subprocess.run([os.path.join(BIN, "torchrun"), "--standalone", "--nproc-per-node", "2", "--no-python",
                        os.path.join(BIN, "posetrain"), "train", "--data", str(tiny_set), "--out", str(out),
                        "--arch", "mobilenet_v3_small", "--size", "32", "--epochs", "1", "-b", "8",
                        "--device", "cpu", "--no-progress", "--workers", "1"],
                       capture_output=True, text=True, env=env, timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "x 2 processes, batch 4 each" in r.stdout
    assert r.stdout.count("epoch 1/1:") == 1                  # one log line: rank 0's
    rows = list(csv.DictReader(open(out / "log.csv")))
    assert len(rows) == 1 and float(rows[0]["train_loss"]) > 0
    assert json.loads((out / "run.json").read_text())["processes"] == 2
    model, ck = load_checkpoint(out / "checkpoint.pth")         # a plain model's weights (no DDP prefix)
    assert ck["epoch"] == 0 and ck["config"]["arch"] == "mobilenet_v3_small"
    assert not any(k.startswith("module.") for k in ck["model"])
    meta = read_metadata(out / "model.onnx")
    assert meta["spherepose.arch"] == "mobilenet_v3_small"
    o = run_onnx(out / "model.onnx", np.zeros((2, 3, 32, 32), np.float32))
    assert o["euler_deg"].shape == (2, 3)
    assert not list(out.glob("*.tmp"))
    # The two processes' checkpoint resumes in one process (any process count that divides the batch).
    assert main(["train", "--resume", str(out / "checkpoint.pth"), "--data", str(tiny_set), "--out", str(out),
                 "--epochs", "2", "--no-progress", "--no-export", "--threads", "1", "--eval-splits", "val"]) == 0
    assert [r["epoch"] for r in csv.DictReader(open(out / "log.csv"))] == ["1", "2"]
