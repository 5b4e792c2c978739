"""The closed loop end to end: firmware ELF in simavr (stagesim), the stage
client over the pty (poserig), the virtual camera rendering the stage's true
angles, and poseinfer's library with the shipped model.

Checks what a user of the rig relies on: the stage reaches each commanded
pose to within one microstep, no command or reply is lost, and the pose
errors stay within what the model's own validation supports.
"""
import csv
import json
import os
import subprocess
from pathlib import Path

import onnx
import pytest

ROOT = Path(__file__).resolve().parents[2]
MODEL = ROOT / "training/models/Texture_3_color.onnx"
NEEDED = [ROOT / "firmware/build/spherepose-stage.elf", ROOT / "sim/stage/build/stagesim",
          ROOT / "host/build/rig/poserig", MODEL]
STEPS_PER_DEG = 800.0  # the firmware's and stagesim's default
# Grid poses, off-grid poses with 3 decimals, the range corners.
PLAN = [(0, 0, 0), (12, -9, 27), (-28.5, 17.25, -3.125), (29.999, -29.999, 0.001),
        (-17.333, 4.875, 21.6), (30, 30, -30)]


def model_metrics(path):
    meta = {p.key: p.value for p in onnx.load(str(path), load_external_data=False).metadata_props}
    assert "spherepose.metrics" in meta, f"{path}: no spherepose.metrics in the model metadata"
    return json.loads(meta["spherepose.metrics"])


@pytest.fixture(scope="module")
def rig_run(tmp_path_factory):
    missing = [str(p.relative_to(ROOT)) for p in NEEDED if not p.exists()]
    assert not missing, f"not built: {missing} (run 'make build')"
    out = tmp_path_factory.mktemp("rig")
    plan = out / "plan.csv"
    plan.write_text("x,y,z\n" + "".join(f"{x},{y},{z}\n" for x, y, z in PLAN))
    env = dict(os.environ, MODEL=str(MODEL), VCAM_OPTS=f"--frame-log {out / 'frames.jsonl'}")
    proc = subprocess.run([str(ROOT / "scripts/simrig.sh"), str(out / "run"), "--plan", str(plan),
                           "--settle", "50", "-v"],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    return out, proc


def test_run_measures_every_pose(rig_run):
    out, proc = rig_run
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    rows = list(csv.DictReader(open(out / "run/poses.csv")))
    assert [r["status"] for r in rows] == ["ok"] * len(PLAN)


def test_stage_reaches_each_pose_within_one_microstep(rig_run):
    out, proc = rig_run
    frames = [json.loads(line) for line in open(out / "frames.jsonl")]
    assert len(frames) == len(PLAN), f"{len(frames)} frames grabbed for {len(PLAN)} poses"
    for cmd, frame in zip(PLAN, frames):
        for axis, want in zip("xyz", cmd):
            assert abs(frame[axis] - want) <= 1.0 / STEPS_PER_DEG, \
                f"pose {cmd}: true {axis} {frame[axis]} is more than one microstep away"


def test_no_command_or_reply_lost(rig_run):
    _, proc = rig_run
    trace = proc.stderr.splitlines()
    sent = [l for l in trace if l.startswith("> ")]
    replies = [l for l in trace if l in ("< ok",) or l.startswith("< error:")]
    assert sent, "the -v trace shows no command"
    assert len(replies) == len(sent), f"{len(sent)} commands sent, {len(replies)} replies"
    assert not [l for l in replies if l.startswith("< error:")]
    assert not [l for l in trace if l.startswith("< ALARM")]


def is_range_corner(pose):
    """All three angles at the edge of the +-30 degree range: the validation split
    (random grid poses) almost never holds such poses, so it says nothing about them;
    the shipped model is measurably worse there (docs/training.md)."""
    return all(abs(a) >= 29.0 for a in pose)


def test_errors_within_the_models_validation(rig_run):
    out, _ = rig_run
    metrics = model_metrics(MODEL)
    val = metrics.get("val", metrics)
    rows = list(csv.DictReader(open(out / "run/poses.csv")))
    kept = [(pose, r) for pose, r in zip(PLAN, rows) if not is_range_corner(pose)]
    assert len(kept) >= 4
    errs = [[float(r[f"err_{a}"]) for a in "xyz"] for _, r in kept]
    mae = sum(map(sum, errs)) / (3 * len(errs))
    # Six poses are a small sample: allow twice the validation MAE plus a tenth of a degree,
    # and no single axis error beyond 1.5 x the largest validation error of that axis.
    assert mae <= 2 * val["mae"] + 0.1, f"rig MAE {mae:.3f} vs validation MAE {val['mae']:.3f}"
    for (pose, _), e in zip(kept, errs):
        for a, ea, vmax in zip("xyz", e, val["max"]):
            assert ea <= 1.5 * vmax + 0.1, f"pose {pose}: {a} error {ea:.3f} (validation max {vmax:.3f})"
