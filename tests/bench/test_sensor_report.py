"""bench/sensor_report.py on three small frames: the by-stage table from a realscene.py-like run
folder and the variants table from bench/sensor_stages.py's folders."""
import json
import os
import shutil
import sys

import cv2
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "bench"))

import sensor_report  # noqa: E402
import sensor_stages  # noqa: E402
from raycast import camera  # noqa: E402

SMALL = camera.Camera(width=160, height=128, pixel_mm=0.0384)


def test_tables(tmp_path, capsys):
    tex = tmp_path / "tex.png"
    cv2.imwrite(str(tex), np.random.default_rng(2).integers(0, 256, (64, 128, 3), dtype=np.uint8))
    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps(SMALL.to_dict()))
    stages = tmp_path / "stages"
    sensor_stages.main(["--seed", "601", "--n", "3", "--texture", str(tex), "--camera", str(cam),
                        "--supersample", "1", "--out", str(stages)])
    # a run folder as bench/realscene.py writes it, every frame answered on its truth
    run = tmp_path / "run"
    (run / "rig-sensor").mkdir(parents=True)
    shutil.copy(stages / "camera.json", run / "camera.json")
    shutil.copy(stages / "all" / "truth.jsonl", run / "rig-sensor" / "truth.jsonl")
    truths = [json.loads(x) for x in (stages / "all" / "truth.jsonl").read_text().splitlines()]
    with open(run / "results.jsonl", "w") as f:
        for t in truths:
            f.write(json.dumps({"family": "rig-sensor", "file": t["file"], "pose": t["pose"], "pred": t["pose"],
                                "circle": t["circle"], "found": t["circle"], "error": None,
                                "confident": True}) + "\n")
    capsys.readouterr()
    sensor_report.main(["--runs", str(run), "--stages", str(stages)])
    out = capsys.readouterr().out
    assert "| all |  | 3 | 3 / 0 | 0 | 0.000 | 0.00 | 0.00 / 0.00 / 0.00 | 0.00 / 0.00 | 3 |" in out
    assert sum(out.count(f"| {c} |") for c in ("RGGB", "BGGR", "GRBG", "GBRG")) == len({t["scene"]["sensor"]["cfa"]
                                                                                         for t in truths})
    variants = out[out.index("The variants located"):]
    rows = [line for line in variants.splitlines() if line.startswith("| ")][2:]   # after the header
    assert [r.split("|")[1].strip() for r in rows] == list(sensor_report.VARIANTS) == list(sensor_stages.VARIANTS)
