"""posetrain train --init MODEL.onnx: an exported model's folded weights, unfolded."""
import json

import cv2
import numpy as np
import pytest
import torch

from training import data, models
from training import preprocess as pp
from training.export import export_onnx
from training.onnx_init import InitError, load_onnx_weights

CONFIG = {"arch": "mobilenet_v2", "head": "euler", "width_mult": 0.25,
          "preprocess": dict(pp.DEFAULTS, size=64)}


def _trained_like(seed):
    """A small network whose BatchNorms hold non-trivial statistics and affine terms."""
    torch.manual_seed(seed)
    m = models.build(CONFIG)
    for mod in m.modules():
        if isinstance(mod, torch.nn.BatchNorm2d):
            n = mod.num_features
            mod.running_mean.uniform_(-0.5, 0.5)
            mod.running_var.uniform_(0.5, 2.0)
            with torch.no_grad():
                mod.weight.uniform_(0.5, 1.5)
                mod.bias.uniform_(-0.2, 0.2)
    return m.eval()


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """(the network, its ONNX file): one export for the module's tests."""
    src = _trained_like(0)
    path = tmp_path_factory.mktemp("onnx_init") / "m.onnx"
    export_onnx(src, CONFIG, path)
    return src, path


def test_onnx_weights_reproduce_the_model(exported):
    src, path = exported
    x = torch.randn(24, 3, 64, 64, generator=torch.Generator().manual_seed(1))
    dst = models.build(CONFIG)
    load_onnx_weights(dst, path, x)
    dst.eval()
    with torch.no_grad():
        a, b = src(x)["euler_deg"], dst(x)["euler_deg"]
    assert torch.allclose(a, b, atol=1e-3), (a - b).abs().max()
    # train mode normalises with the batch's own statistics, which step 3 made the recorded ones
    dst.train()
    with torch.no_grad():
        c = dst(x)["euler_deg"]
    assert torch.allclose(a, c, atol=1e-2), (a - c).abs().max()


def test_onnx_of_another_width_is_refused(exported):
    _, path = exported
    other = models.build(dict(CONFIG, width_mult=0.5))
    with pytest.raises(InitError, match="m.onnx"):
        load_onnx_weights(other, path, torch.zeros(2, 3, 64, 64))


def test_not_an_onnx_file_is_named(tmp_path):
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not a model")
    with pytest.raises(InitError, match="bad.onnx"):
        load_onnx_weights(models.build(CONFIG), bad, torch.zeros(2, 3, 64, 64))


def test_frames_the_localisation_refuses_are_left_out_and_named(tmp_path, frame, capsys):
    split = tmp_path / "train"
    split.mkdir()
    for i, name in enumerate(["1_2_3.png", "-4_5_6.png"]):
        cv2.imwrite(str(split / name), frame(i))
    cv2.imwrite(str(split / "7_8_9.png"), np.full((128, 160, 3), 64, np.uint8))  # no sphere
    crops, labels, names = data.load_crops(split, pp.params(), cache=True, progress=False)
    assert names == ["-4_5_6.png", "1_2_3.png"]
    assert labels.tolist() == [[-4, 5, 6], [1, 2, 3]]
    assert len(crops) == 2
    assert "7_8_9.png" in capsys.readouterr().err
    again = data.load_crops(split, pp.params(), cache=True, progress=False)  # from the cache
    assert again[2] == names and np.array_equal(again[0], crops)


def test_truth_record_gives_each_frame_its_camera(tmp_path):
    split = tmp_path / "train"
    split.mkdir()
    rec = {"file": "1_2_3.png", "pose": [1, 2, 3], "circle": [80, 64, 40],
           "scene": {"camera": {"focal_px": 1700.0, "principal_px": [81.0, 63.0],
                                "distortion": [-0.1, 0.02, 0, 0, 0], "distance_mm": 240.0}}}
    (split / "truth.jsonl").write_text(json.dumps(rec) + "\n")
    cams = data.frame_cameras(split)
    cam = cams["1_2_3.png"]
    assert cam["focal_mm"] / cam["pixel_mm"] == pytest.approx(1700.0)
    assert cam["principal_px"] == [81.0, 63.0] and cam["distance_mm"] == 240.0
    (split / "truth.jsonl").write_text("{not json\n")
    with pytest.raises(data.DatasetError, match="truth.jsonl:1"):
        data.frame_cameras(split)
