"""sphere-crop-v2 without a camera file searches radii of 5-50 % of the frame's smaller side.
On this clean render of Texture_3_color at the reference camera the texture's own arcs add up
to coarse peaks of large circles mostly outside the frame, stronger than the rim's; they used
to take every candidate place and the frame was refused ("no sphere found"). A peak whose
circle would be refused as cut by the frame edge no longer uses up a place: C and Python find
the sphere, the same circle on both sides."""
import json
import os
import subprocess
from pathlib import Path

import cv2
import pytest

from textures.generate import render as texture_rgb
from training import preprocess as pp
from training.export import read_metadata

REPO = Path(__file__).resolve().parents[2]
MODEL = REPO / "training" / "models" / "Texture_3_color.onnx"
POSE = ("-29.0", "18.8", "24.8")


def test_wide_search_finds_the_sphere_on_both_sides(tmp_path):
    exe = Path(os.environ.get("POSEINFER", REPO / "host" / "build" / "poseinfer"))
    sim = REPO / ".venv" / "bin" / "sim"
    for need in (exe, sim):
        assert need.exists(), f"{need} is not built (make build)"
    tex = tmp_path / "Texture_3_color.png"
    cv2.imwrite(str(tex), texture_rgb(3, "color")[:, :, ::-1])
    frame = tmp_path / "frame.png"
    subprocess.run([str(sim), "render", "--texture", str(tex), "--pose", *POSE, "--out", str(frame)],
                   check=True, capture_output=True, timeout=300)
    p = pp.params(read_metadata(MODEL)["spherepose.preprocess"], model=MODEL.name)
    cx, cy, r, _ = pp.find_sphere(cv2.imread(str(frame)), p)
    # the reference camera puts the sphere's centre at the frame's centre, r about 133.7 px
    assert abs(cx - 319.5) < 0.5 and abs(cy - 255.5) < 0.5 and abs(r - 133.7) < 0.7, (cx, cy, r)
    # unrefined: a refined answer's circle can be the rim found from the refined circle
    proc = subprocess.run([str(exe), "--model", str(MODEL), "--no-refine", str(frame)], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    line = json.loads(proc.stdout.splitlines()[0])
    assert "error" not in line, line
    assert line["circle"] == [round(cx + 0.5, 3), round(cy + 0.5, 3), round(r, 3)], line
