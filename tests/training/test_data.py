"""Datasets: labels from names, the cache, preprocessing parity, and bad inputs."""
import cv2
import numpy as np
import pytest
import torch

from sim.names import BadName
from training import preprocess as pp
from training.cli import main
from training.data import CACHE_PREFIX, DatasetError, PoseSet, check_label_ranges, prepare_batch



def _write(d, name, seed=0):
    cv2.imwrite(str(d / name), _frame(seed))


@pytest.fixture(autouse=True)
def _use_frame(frame):
    global _frame
    _frame = frame


def test_labels_cache_and_preprocessing_parity(tmp_path):
    names = ["1_2_3.png", "-4.5_0_30.png", "7.125_-3.25_-14.5.png"]
    for i, n in enumerate(names):
        _write(tmp_path, n, i)
    (tmp_path / "dataset.json").write_text("{}")  # other files are ignored
    p = pp.params({"size": 64})
    ds = PoseSet(tmp_path, p, progress=False)
    by_name = dict(zip(ds.names, ds.labels.tolist()))
    assert by_name["-4.5_0_30.png"] == [-4.5, 0.0, 30.0]
    assert by_name["7.125_-3.25_-14.5.png"] == [7.125, -3.25, -14.5]
    # the batch path (cached uint8 crops, torch normalise) equals preprocess_file exactly
    x = prepare_batch(ds.images, p).numpy()
    for i, n in enumerate(ds.names):
        ref = pp.preprocess_file(tmp_path / n, p)
        assert np.abs(x[i] - ref).max() < 1e-6
    caches = list(tmp_path.glob(CACHE_PREFIX + "*.npz"))
    assert len(caches) == 1
    # unchanged folder: served from the cache; a new frame or new params: rebuilt
    assert torch.equal(PoseSet(tmp_path, p, progress=False).images, ds.images)
    _write(tmp_path, "0_0_0.png", 9)
    assert len(PoseSet(tmp_path, p, progress=False)) == 4
    assert len(list(tmp_path.glob(CACHE_PREFIX + "*.npz"))) == 1  # the stale one is gone
    assert len(PoseSet(tmp_path, pp.params({"size": 48}), progress=False)) == 4
    assert len(list(tmp_path.glob(CACHE_PREFIX + "*.npz"))) == 2  # one per parameter set


@pytest.mark.parametrize("bad", ["pose.png", "1_2.png", "01_2_3.png", "1_2_3.1234.png", "+1_2_3.png"])
def test_malformed_name_names_the_file(tmp_path, bad):
    _write(tmp_path, "1_2_3.png")
    _write(tmp_path, bad)
    with pytest.raises(BadName, match=bad.replace("+", r"\+").replace(".", r"\.")):
        PoseSet(tmp_path, pp.params(), progress=False)


def test_empty_split(tmp_path):
    with pytest.raises(DatasetError, match="empty split"):
        PoseSet(tmp_path, pp.params(), progress=False)
    with pytest.raises(DatasetError, match="not a folder"):
        PoseSet(tmp_path / "missing", pp.params(), progress=False)


def test_corrupt_png_and_no_sphere(tmp_path):
    _write(tmp_path, "1_2_3.png")
    (tmp_path / "4_5_6.png").write_bytes(b"\x89PNG\r\n\x1a\nnot really")
    with pytest.raises(DatasetError, match=r"4_5_6\.png: cannot decode"):
        PoseSet(tmp_path, pp.params(), progress=False)
    (tmp_path / "4_5_6.png").unlink()
    # a frame without a sphere is left out, and named (test_onnx_init.py has the warning);
    # a split where the sphere is found in no frame at all is an error naming one of them
    cv2.imwrite(str(tmp_path / "7_8_9.png"), np.full((100, 120, 3), 64, np.uint8))
    assert PoseSet(tmp_path, pp.params(), progress=False).names == ["1_2_3.png"]
    (tmp_path / "1_2_3.png").unlink()
    with pytest.raises(DatasetError, match=r"7_8_9\.png: no sphere found"):
        PoseSet(tmp_path, pp.params(), progress=False)


def test_cli_reports_bad_input_and_choices(tmp_path, capsys):
    (tmp_path / "train").mkdir()
    (tmp_path / "val").mkdir()
    _write(tmp_path / "train", "oops.png")
    assert main(["train", "--data", str(tmp_path), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    assert "oops.png" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["train", "--data", str(tmp_path), "--out", "o", "--arch", "resnet"])
    assert "mobilenet_v3_small" in capsys.readouterr().err


def test_labels_outside_the_model_ranges_are_named(tmp_path, capsys):
    """400_0_0.png is a valid name but no pose of the model's ranges (+-30 degrees): a warning names it
    and training goes on; --strict refuses the run (exit 2) with the same names."""
    (tmp_path / "train").mkdir()
    (tmp_path / "val").mkdir()
    for i, n in enumerate(["1_2_3.png", "400_0_0.png", "0_30_-31.5.png", "-30_30_30.png"]):
        _write(tmp_path / "train", n, i)
    _write(tmp_path / "val", "0_0_0.png", 7)
    ranges = {a: [-30, 30] for a in "xyz"}
    ds = PoseSet(tmp_path / "train", pp.params({"size": 32}), progress=False)
    problems = check_label_ranges(ds, ranges)
    assert problems == ["0_30_-31.5.png (z -31.5 outside -30..30)", "400_0_0.png (x 400 outside -30..30)"]
    err = capsys.readouterr().err
    assert "warning" in err and "2 of 4 frames" in err and "400_0_0.png" in err and "--strict" in err
    with pytest.raises(DatasetError, match=r"400_0_0\.png \(x 400 outside"):
        check_label_ranges(ds, ranges, strict=True)
    common = ["train", "--data", str(tmp_path), "--no-progress", "--size", "32", "--arch", "mobilenet_v3_small",
              "--epochs", "1", "-b", "2", "--threads", "1", "--no-export", "--eval-splits"]
    assert main([*common, "--out", str(tmp_path / "strict"), "--strict"]) == 2
    err = capsys.readouterr().err
    assert "error" in err and "400_0_0.png" in err and "0_30_-31.5.png" in err and "1_2_3.png" not in err
    assert main([*common, "--out", str(tmp_path / "warn")]) == 0
    err = capsys.readouterr().err
    assert "warning" in err and "400_0_0.png" in err


def test_augmentation_shapes_and_range():
    g = torch.Generator().manual_seed(0)
    imgs = torch.randint(0, 256, (4, 3, 32, 32), dtype=torch.uint8)
    p = pp.params({"size": 32})
    x = prepare_batch(imgs, p, {"photometric": 1.0, "geometric": True}, g)
    assert x.shape == (4, 3, 32, 32) and torch.isfinite(x).all()
    assert not torch.allclose(x, prepare_batch(imgs, p))


def test_gray_augmentation_is_what_a_mono_camera_gives():
    """--gray: a crop made gray in training is what preprocess.py makes of a mono camera's
    frame (OpenCV's BGR2GRAY, widened to three equal channels), to within rounding."""
    import cv2
    import numpy as np
    from training.data import gray
    rng = np.random.default_rng(5)
    bgr = rng.integers(0, 256, (16, 16, 3), dtype=np.uint8)
    mono = cv2.cvtColor(cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY), cv2.COLOR_GRAY2BGR)
    rgb = torch.tensor(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)).permute(2, 0, 1)[None].float() / 255
    g = torch.Generator().manual_seed(0)
    assert torch.equal(gray(rgb, g, 0.0), rgb)
    got = gray(rgb, g, 1.0)[0].permute(1, 2, 0).numpy() * 255
    assert np.abs(got - mono.astype(np.float32)).max() <= 0.5 + 1e-4
    x = torch.rand(64, 3, 4, 4, generator=g)
    some = gray(x, g, 0.5)
    made_gray = [bool(torch.equal(s[0], s[1]) and torch.equal(s[1], s[2])) for s in some]
    assert 16 < sum(made_gray) < 48  # about half, each sample drawn on its own
