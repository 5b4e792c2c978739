"""bench/infer_bench.py's report plumbing: the BMP copies it times beside PNG hold the
same pixels, and rewriting the report keeps the sections it does not write exactly once."""
import os
import sys

import cv2
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "bench"))

import infer_bench  # noqa: E402


def test_bmp_copies_same_pixels_and_replaced_when_stale(tmp_path):
    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, (40, 56, 3), dtype=np.uint8)
    png = tmp_path / "a.png"
    cv2.imwrite(str(png), img)
    (bmp,) = infer_bench.bmp_copies([png], tmp_path)
    assert np.array_equal(cv2.imread(str(bmp), cv2.IMREAD_UNCHANGED), img)
    cv2.imwrite(str(png), 255 - img)  # the frame changed: its copy must follow
    (bmp,) = infer_bench.bmp_copies([png], tmp_path)
    assert np.array_equal(cv2.imread(str(bmp), cv2.IMREAD_UNCHANGED), 255 - img)
    assert sorted(p.name for p in bmp.parent.iterdir()) == ["a.bmp"]  # no temporary left


def test_kept_sections_skip_what_the_script_writes(tmp_path):
    old = tmp_path / "host.md"
    old.write_text("# Host runtime benchmark\n\n| a |\n\n## Reading\n\n- x\n\n"
                   f"{infer_bench.WRITTEN_SECTIONS[1]}\n\n| PNG | 1 |\n\n## Someone's notes\n\nkept\n")
    assert infer_bench.kept_sections(old) == ["## Someone's notes", "", "kept", ""]
