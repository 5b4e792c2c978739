"""`sim dataset`: pose plan, record, refusal to mix arguments, determinism, resume after a kill."""
import hashlib
import json
import os
import signal
import subprocess
import sys
import time

import cv2
import pytest

from sim import names
from sim.dataset import SPLITS, DatasetConfig, DatasetError, build, grid_values, plan

SMALL = ["--train", "24", "--val", "8", "--test", "4", "--offgrid-test", "4"]


def run_sim(*args, check=True):
    r = subprocess.run([sys.executable, "-m", "sim.cli", *args], capture_output=True, text=True)
    if check:
        assert r.returncode == 0, r.stderr
    return r


def tree_digest(folder):
    """{relative path: sha256} of every frame of a dataset folder."""
    out = {}
    for split in SPLITS:
        d = os.path.join(folder, split)
        if os.path.isdir(d):
            for name in os.listdir(d):
                with open(os.path.join(d, name), "rb") as f:
                    out[f"{split}/{name}"] = hashlib.sha256(f.read()).hexdigest()
    return out


# ---- the pose plan (no rendering) -------------------------------------------

def test_p1_plan_matches_the_protocol(tmp_path):
    poses = plan(DatasetConfig(texture="unused.png"))
    by_split = {s: [p for _, sp, p in poses if sp == s] for s in SPLITS}
    assert {s: len(v) for s, v in by_split.items()} == {"train": 1600, "val": 597, "test": 100, "test_offgrid": 100}
    grid = set(grid_values(-30, 30, 3))
    assert len(grid) == 21
    everything = [p for _, _, p in poses]
    assert len(set(everything)) == len(everything), "a pose repeats"
    for s in ("train", "val", "test"):
        assert all(all(a in grid for a in p) for p in by_split[s])
    for p in by_split["test_offgrid"]:
        assert not all(a in grid for a in p) and all(-30 <= a <= 30 for a in p)
        assert names.parse_name(names.format_name(*p)) == p
    assert [i for i, _, _ in poses] == list(range(len(poses)))


def test_plan_depends_on_seed_only():
    a = plan(DatasetConfig(texture="t", seed=1))
    assert a == plan(DatasetConfig(texture="t", seed=1))
    assert a != plan(DatasetConfig(texture="t", seed=2))


def test_grid_budget_and_ranges_are_checked():
    with pytest.raises(DatasetError, match="grid has only 9261"):
        plan(DatasetConfig(texture="t", counts={"train": 9000, "val": 597, "test": 100}))
    with pytest.raises(DatasetError, match="not a whole number of steps"):
        plan(DatasetConfig(texture="t", ranges={"x": (-30, 29), "y": (-30, 30), "z": (-30, 30)}))
    with pytest.raises(DatasetError, match="unknown sampling"):
        plan(DatasetConfig(texture="t", sampling="random"))


def test_continuous_sampling_goes_past_the_grid_budget():
    poses = plan(DatasetConfig(texture="t", sampling="continuous",
                               counts={"train": 12000, "val": 500, "test": 100, "test_offgrid": 100}))
    train = [p for _, s, p in poses if s == "train"]
    assert len(train) == 12000 and len(set(p for _, _, p in poses)) == len(poses)
    assert all(-30 <= a <= 30 for p in train for a in p)
    assert all(names.quantize(*p) == p for p in train)


# ---- rendering ----------------------------------------------------------------

def test_record_and_layout(tmp_path, texture_png, small_camera_json):
    out = tmp_path / "ds"
    run_sim("dataset", "--texture", texture_png, "--camera", small_camera_json, "--out", str(out),
            "--seed", "5", "--quiet", "--noise", "2", *SMALL)
    rec = json.loads((out / "dataset.json").read_text())
    assert rec["complete"] is True
    assert rec["command"].startswith("sim dataset --texture")
    assert rec["texture"]["sha256"] == hashlib.sha256(open(texture_png, "rb").read()).hexdigest()
    assert rec["settings"]["seed"] == 5
    assert rec["settings"]["camera"]["width"] == 160
    assert rec["settings"]["randomization"]["noise"] == 2.0
    assert rec["counts"] == {"train": 24, "val": 8, "test": 4, "test_offgrid": 4}
    for split, n in rec["counts"].items():
        files = sorted(f for f in os.listdir(out / split) if f != "truth.jsonl")
        assert len(files) == n
        for name in files:
            names.parse_name(name)
        truth = [json.loads(line) for line in open(out / split / "truth.jsonl")]
        assert sorted(t["file"] for t in truth) == files
        assert all(t["circle"] == [80.0, 64.0, truth[0]["circle"][2]] for t in truth)  # no offset or scale
    img = cv2.imread(str(out / split / files[0]))
    assert img.shape == (128, 160, 3)


def test_refuses_to_resume_with_other_arguments(tmp_path, texture_png, small_camera_json):
    out = tmp_path / "ds"
    args = ["dataset", "--texture", texture_png, "--camera", small_camera_json, "--out", str(out), "--quiet"]
    run_sim(*args, *SMALL)
    r = run_sim(*args, "--seed", "1", "--blur", "0.5", *SMALL, check=False)
    assert r.returncode != 0
    assert "different arguments" in r.stderr and "seed" in r.stderr and "randomization.blur" in r.stderr
    # A folder that is not a dataset is not touched either.
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    r = run_sim("dataset", "--texture", texture_png, "--out", str(other), "--quiet", *SMALL, check=False)
    assert r.returncode != 0 and "not a dataset folder" in r.stderr


def test_out_that_is_a_file_is_a_named_error_exit_2(tmp_path, texture_png):
    """--out naming an existing file (or a path through one): a message naming it, exit 2, no traceback,
    the file untouched."""
    f = tmp_path / "notes.txt"
    f.write_text("mine")
    for out in (f, f / "ds"):
        r = run_sim("dataset", "--texture", texture_png, "--out", str(out), "--quiet", *SMALL, check=False)
        assert r.returncode == 2, r.stderr
        assert str(f) in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert "exists and is not a folder" in run_sim("dataset", "--texture", texture_png, "--out", str(f),
                                                   "--quiet", *SMALL, check=False).stderr
    assert f.read_text() == "mine"


def test_same_seed_same_bytes_any_worker_count(tmp_path, texture_png, small_camera_json):
    common = ["--texture", texture_png, "--camera", small_camera_json, "--quiet", "--randomize", *SMALL]
    run_sim("dataset", *common, "--out", str(tmp_path / "a"), "--workers", "1")
    run_sim("dataset", *common, "--out", str(tmp_path / "b"), "--workers", "2")
    run_sim("dataset", *common, "--out", str(tmp_path / "c"), "--workers", "2", "--seed", "1")
    a, b, c = (tree_digest(tmp_path / k) for k in "abc")
    assert len(a) == 40 + 4 and a == b  # frames and each split's truth.jsonl
    assert a != c


def test_resume_after_kill_gives_the_uninterrupted_dataset(tmp_path, texture_png, small_camera_json):
    """Kill a real run (SIGKILL to its whole process group) mid-way; the rerun completes it byte for byte."""
    counts = ["--train", "500", "--val", "60", "--test", "20", "--offgrid-test", "20"]
    common = ["--texture", texture_png, "--camera", small_camera_json, "--quiet", "--noise", "3", *counts]
    killed = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, "-m", "sim.cli", "dataset", *common, "--out", str(killed),
                             "--workers", "2"], start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        if len(os.listdir(killed / "train")) >= 60 if (killed / "train").is_dir() else False:
            break
        time.sleep(0.02)
    assert proc.poll() is None, "the run finished before it could be killed; make it longer"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    # Frames only: a worker killed mid-write leaves its temporary '.part' file, never a half PNG.
    partial = {k: v for k, v in tree_digest(killed).items() if k.endswith(".png")}
    assert 0 < len(partial) < 600
    for rel in partial:  # every frame that exists is a whole PNG (atomic writes)
        assert cv2.imread(str(killed / rel)) is not None, rel
    assert json.loads((killed / "dataset.json").read_text())["complete"] is False

    run_sim("dataset", *common, "--out", str(killed), "--workers", "2")
    rec = json.loads((killed / "dataset.json").read_text())
    assert rec["last_run"]["rendered"] == 600 - len(partial), "the rerun rendered more than the missing frames"
    full = tmp_path / "full"
    run_sim("dataset", *common, "--out", str(full), "--workers", "2")
    resumed, reference = tree_digest(killed), tree_digest(full)
    assert len(reference) == 600 + 4 and resumed == reference  # frames and each split's truth.jsonl
    for split in SPLITS:
        assert not [n for n in os.listdir(killed / split) if not n.endswith((".png", ".jsonl"))], \
            "temporary files left"
    assert json.loads((killed / "dataset.json").read_text())["complete"] is True


def test_resume_renders_damaged_frames_again(tmp_path, texture_png, small_camera_json):
    """A frame cut to 0 or 1000 bytes, or with a flipped byte, is not taken as done for existing: the
    resume names it, renders it again, and the folder is the uninterrupted dataset byte for byte."""
    out = tmp_path / "ds"
    args = ["dataset", "--texture", texture_png, "--camera", small_camera_json, "--out", str(out), *SMALL]
    run_sim(*args, "--quiet")
    reference = tree_digest(out)
    victims = {split: sorted(os.listdir(out / split))[0] for split in ("train", "val", "test")}
    (out / "train" / victims["train"]).write_bytes(b"")
    frame = out / "val" / victims["val"]
    assert frame.stat().st_size > 1000
    frame.write_bytes(frame.read_bytes()[:1000])
    flipped = bytearray((out / "test" / victims["test"]).read_bytes())
    flipped[len(flipped) // 2] ^= 0xFF
    (out / "test" / victims["test"]).write_bytes(bytes(flipped))
    r = run_sim(*args, "--workers", "2")
    assert "3 frames damaged, rendered again" in r.stderr, r.stderr
    for split, name in victims.items():
        assert f"{split}/{name}" in r.stderr
    assert "empty file" in r.stderr and "1000 bytes" in r.stderr
    rec = json.loads((out / "dataset.json").read_text())
    assert rec["complete"] is True
    assert rec["last_run"]["rendered"] == 3 and rec["last_run"]["damaged_rendered_again"] == 3
    assert tree_digest(out) == reference
    # Whole frames are trusted: a second resume renders nothing.
    run_sim(*args, "--quiet")
    assert json.loads((out / "dataset.json").read_text())["last_run"]["rendered"] == 0


def test_build_in_process_checks_texture(tmp_path):
    with pytest.raises(DatasetError, match="texture file not found"):
        build(DatasetConfig(texture=str(tmp_path / "missing.png")), str(tmp_path / "out"), progress=False)
