"""A short training on a tiny rendered set lowers the loss; ONNX export matches PyTorch; eval works."""
import csv
import json

import cv2
import numpy as np
import pytest

from training.cli import main
from training.export import read_metadata, run_onnx

render = pytest.importorskip("sim.render")
from sim.camera import Camera  # noqa: E402
from sim.names import format_name  # noqa: E402


def _texture(seed=0):
    """Random patches in four colours: test data for the renderer, not a designed texture."""
    rng = np.random.default_rng(seed)
    pal = np.array([[230, 230, 230], [20, 20, 20], [40, 160, 60], [40, 70, 200]], np.uint8)
    idx = rng.integers(0, 4, (16, 32))
    return np.kron(pal[idx], np.ones((16, 16, 1), np.uint8)).reshape(256, 512, 3)


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("tiny")
    cam = Camera(width=96, height=80, focal_mm=16.0 * 96 / 640)
    r = render.Renderer(_texture(), cam)
    rng = np.random.default_rng(0)
    for split, n in (("train", 64), ("val", 16), ("test", 8)):
        (root / split).mkdir()
        for pose in rng.uniform(-30, 30, (n, 3)).round(1):
            cv2.imwrite(str(root / split / format_name(*pose)), r.render(tuple(pose))[:, :, ::-1])
    r.close()
    (root / "dataset.json").write_text(json.dumps({"texture": "tiny_patches.png", "seed": 0}))
    return root


@pytest.mark.slow
@pytest.mark.parametrize("head", ["euler", "rot6d"])
def test_short_training_lowers_loss_and_exports(tiny_dataset, tmp_path, head):
    out = tmp_path / "run"
    # 6 epochs: with 4 the rot6d head's loss, which rises in the second epoch, ended 0.80 of the
    # first's, at the 0.8 below (its crops moved by 0.08 px with the rim refit); with 6, 0.61
    rc = main(["train", "--data", str(tiny_dataset), "--out", str(out), "--arch", "mobilenet_v3_small",
               "--head", head, "--size", "32", "--epochs", "6", "-b", "8", "--lr", "2e-3",
               "--no-progress", "--threads", "1"])
    assert rc == 0
    rows = list(csv.DictReader(open(out / "log.csv")))
    assert len(rows) == 6
    assert float(rows[-1]["train_loss"]) < 0.8 * float(rows[0]["train_loss"])
    for f in ("best.pth", "checkpoint.pth", "tables.md", "metrics.json", "metrics_val.json",
              "val_fig3_error_distribution.png", "val_fig4_test_panels.png", "val_fig6_box.png", "model.onnx"):
        assert (out / f).exists(), f
    meta = read_metadata(out / "model.onnx")
    assert json.loads(meta["spherepose.preprocess"])["size"] == 32
    assert meta["spherepose.texture"] == "tiny_patches"
    assert meta["spherepose.head"] == head and meta["spherepose.arch"] == "mobilenet_v3_small"
    assert meta["spherepose.euler"] == "R = Rz(z) Ry(y) Rx(x), degrees, body to world"
    assert "mae" in json.loads(meta["spherepose.metrics"])
    # ONNX (through the eval command) gives the same numbers as the checkpoint
    assert main(["eval", "--model", str(out / "model.onnx"), "--data", str(tiny_dataset),
                 "--out", str(tmp_path / "e_onnx"), "--no-progress", "--threads", "1"]) == 0
    assert main(["eval", "--model", str(out / "best.pth"), "--data", str(tiny_dataset),
                 "--out", str(tmp_path / "e_pth"), "--no-progress", "--threads", "1"]) == 0
    a = json.loads((tmp_path / "e_onnx" / "metrics.json").read_text())
    b = json.loads((tmp_path / "e_pth" / "metrics.json").read_text())
    assert set(a) == {"val", "test"}
    assert abs(a["test"]["mae"] - b["test"]["mae"]) < 1e-4
    if head == "rot6d":
        o = run_onnx(out / "model.onnx", np.zeros((2, 3, 32, 32), np.float32))
        assert o["rotmat"].shape == (2, 3, 3)
    # resume: one more epoch continues the log
    assert main(["train", "--resume", str(out / "checkpoint.pth"), "--data", str(tiny_dataset),
                 "--out", str(out), "--epochs", "7", "--no-progress", "--no-export", "--threads", "1"]) == 0
    assert len(list(csv.DictReader(open(out / "log.csv")))) == 7
