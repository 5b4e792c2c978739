"""The criteria checker: verdicts on the six textures, symmetric textures failing, bad inputs."""
import io
import json
from contextlib import redirect_stderr, redirect_stdout

import cv2
import numpy as np
import pytest
from PIL import Image

from textures import cli, generate
from textures.criteria import area_ratio, check_texture, colour_difference, stripe_spacing, uniqueness_check
from textures.palette import find_palette

from texhelpers import TEST_STEP, bw_image

SIX = [generate.texture_name(l, v) for l in generate.LEVELS for v in generate.VERSIONS]


def run_cli(*argv):
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        rc = cli.main(list(argv))
    return rc, out.getvalue(), err.getvalue()


@pytest.mark.parametrize("name", SIX)
def test_six_textures_pass_every_criterion(six_reports, name):
    rep = six_reports[name]
    for crit in ("stripe spacing ratio", "texture:blank area ratio", "colour difference dE2000",
                 "orientation uniqueness"):
        assert rep[crit]["passed"] is True, (name, crit, rep[crit])
    assert rep["stripe spacing ratio"]["value"] >= 5.0
    for t in ("Tamura coarseness", "Tamura contrast", "Tamura directionality"):
        assert rep[t]["passed"] is None and rep[t]["value"] is not None


def test_texture1_has_the_smallest_uniqueness_margin(six_reports):
    u = {n: six_reports[n]["orientation uniqueness"]["value"] for n in SIX}
    for v in ("bw", "color"):
        assert u[f"Texture_1_{v}"] < u[f"Texture_2_{v}"]
        assert u[f"Texture_1_{v}"] < u[f"Texture_3_{v}"]


def test_bw_and_color_share_spacing_and_area(six_reports):
    for level in generate.LEVELS:
        bw, col = six_reports[f"Texture_{level}_bw"], six_reports[f"Texture_{level}_color"]
        for crit in ("stripe spacing ratio", "texture:blank area ratio"):
            assert bw[crit]["value"] == col[crit]["value"]


def test_full_p1_grid_on_texture1(tmp_path):
    """The real P1 scan (3 degree grid, 9261 poses) on the texture with the least margin."""
    rgb = generate.render(1, "bw", 512, 256)
    checks, _ = check_texture(rgb, step=3.0, progress=False)
    u = {c["name"]: c for c in checks}["orientation uniqueness"]
    assert u["passed"] is True
    assert u["scan"]["poses"] == 21 ** 3


def _bands():
    """Texture 1 without its gaps: full latitude circles, symmetric about the pole."""
    rects = [(lat - 5.5, lat + 5.5, -180.0, 180.0, 1) for lat in generate.STRIPE_LATS]
    return bw_image(generate.rasterize(rects, 512, 256) > 0)


def _period45():
    """A pattern repeating every 45 degrees of longitude."""
    rects = []
    for k in range(8):
        c = -180.0 + 45.0 * k
        rects += [(-70, 70, c, c + 16, 1), (15, 35, c + 16, c + 30, 1), (-45, -25, c + 20, c + 40, 1),
                  (50, 65, c + 16, c + 40, 1)]
    return bw_image(generate.rasterize(rects, 512, 256) > 0)


def _only_uniqueness_fails(rgb, step):
    checks, _ = check_texture(rgb, step=step, progress=False)
    by = {c["name"]: c for c in checks}
    failed = [c["name"] for c in checks if c["passed"] is False]
    assert failed == ["orientation uniqueness"], failed
    return by["orientation uniqueness"]


def test_latitude_bands_fail_uniqueness_and_name_two_poses():
    u = _only_uniqueness_fails(_bands(), TEST_STEP)
    assert u["passed"] is False and u["value"] < 0.01
    near = u["scan"]["near"]
    assert near["pose_a"] != near["pose_b"] and near["geodesic_deg"] >= 3.0 - 0.05
    assert "(" in u["details"] and str(near["pose_a"][0]).rstrip("0").rstrip(".") in u["details"]


def test_longitude_period_45_fails_uniqueness_with_poses_45_degrees_apart():
    u = _only_uniqueness_fails(_period45(), 5.0)   # 45 = 9 steps of 5 degrees
    assert u["passed"] is False
    far = u["scan"]["far"]
    assert far["ratio"] < 0.01
    assert abs(far["geodesic_deg"] - 45.0) < 1.0


def _period30(block, width=768, seed=0):
    """Random black/white blocks of `block` texels in a tile 30 degrees wide (64 texels at width 768),
    repeated 12 times around the sphere: views 30 degrees apart about the pole are exact twins."""
    h, tile = width // 2, width // 12
    rng = np.random.default_rng(seed)
    cells = rng.random((-(-h // block), -(-tile // block))) < 0.5
    tile_mask = np.kron(cells, np.ones((block, block), bool))[:h, :tile]
    return bw_image(np.tile(tile_mask, (1, 12)))


@pytest.mark.parametrize("block,kind", [(2, "fine"), (16, "coarse")])
def test_longitude_period_30_gives_u_zero(block, kind):
    """A 30 degree period must survive the scan: fine blocks (2 texels, about 1 degree) once passed with
    U = 0.27 and coarse ones got U = 0.13, because the texture was shrunk so that 30 degrees was no whole
    number of texels; views as the camera sees them make the twins exact at any grain."""
    u = uniqueness_check(_period30(block), step=3.0, progress=False)    # 30 = 10 steps of 3 degrees
    assert u["passed"] is False, (kind, u["details"])
    assert u["value"] == 0.0, (kind, u["details"])
    near = u["scan"]["near"]
    assert near["pose_a"][0] == near["pose_b"][0] and near["pose_a"][2] == near["pose_b"][2]
    assert abs(near["geodesic_deg"] - 30.0) < 0.1


def test_cli_fails_symmetric_texture_with_exit_1(tmp_path):
    p = tmp_path / "bands.png"
    Image.fromarray(_bands()).save(p)
    rc, out, _ = run_cli("check", str(p), "--json", "--step", "6", "--no-progress")
    assert rc == 1
    doc = json.loads(out)
    assert doc["pass"] is False
    u = [c for c in doc["criteria"] if c["name"] == "orientation uniqueness"][0]
    assert u["passed"] is False and u["scan"]["near"]["pose_a"] != u["scan"]["near"]["pose_b"]


def test_cli_table_and_exit_0_on_a_paper_texture(texture_dir):
    rc, out, _ = run_cli("check", str(texture_dir / "Texture_3_color.png"), "--step", "6", "--no-progress")
    assert rc == 0
    assert "verdict: PASS" in out and "orientation uniqueness" in out and "Tamura contrast" in out


def test_palette_survives_jpeg_and_antialiasing(tmp_path):
    rgb = generate.render(3, "color", 1024, 512)
    # Antialiased: drawn at twice the size, area-averaged down.
    aa = cv2.resize(generate.render(3, "color", 2048, 1024), (1024, 512), interpolation=cv2.INTER_AREA)
    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, format="JPEG", quality=85)
    jpg = np.asarray(Image.open(io.BytesIO(buf.getvalue())).convert("RGB"))
    ref = find_palette(rgb)
    for img in (aa, jpg):
        pal = find_palette(img)
        assert len(pal.lab) == 4, pal.lab
        ink = pal.labels != pal.blank
        s = stripe_spacing(ink)
        assert s["passed"] and abs(s["value"] - stripe_spacing(ref.labels != ref.blank)["value"]) < 0.3
        assert area_ratio(ink)["passed"]
        assert colour_difference(pal)["passed"]


def test_close_colours_fail_delta_e():
    rgb = _bands().copy()
    rgb[rgb[..., 0] == 0] = 70          # dark grey (L* 29) for the black stripes ...
    top = rgb[:128]                     # ... except in the upper half
    top[top[..., 0] == 70] = 0
    pal = find_palette(rgb)
    assert len(pal.lab) == 3
    c = colour_difference(pal)
    assert c["passed"] is False and c["value"] < 30


def test_fine_stripes_fail_spacing_and_blank_texture_fails_area():
    h = 256
    fine = [(lat, lat + 4.0, -180.0, 180.0, 1) for lat in np.arange(-80, 80, 8.0)]   # 8 deg period
    ink = generate.rasterize(fine, 2 * h, h) > 0
    s = stripe_spacing(ink)
    assert s["passed"] is False and abs(s["value"] - 8.0 / 360 * 100) < 0.3
    sparse = generate.rasterize([(0, 10, -180, 180, 1)], 2 * h, h) > 0
    assert area_ratio(sparse)["passed"] is False


def test_not_a_png_wrong_aspect_and_missing_file_exit_2(tmp_path):
    bad = tmp_path / "notes.png"
    bad.write_text("not an image")
    rc, _, err = run_cli("check", str(bad))
    assert rc == 2 and str(bad) in err and "not a readable image" in err
    square = tmp_path / "square.png"
    Image.fromarray(np.zeros((100, 100, 3), np.uint8)).save(square)
    rc, _, err = run_cli("check", str(square))
    assert rc == 2 and str(square) in err and "twice as wide" in err
    rc, _, err = run_cli("check", str(tmp_path / "missing.png"))
    assert rc == 2 and "missing.png" in err


@pytest.mark.parametrize("sub", [[], ["generate"], ["check"], ["export-sphere"]])
def test_help_states_defaults(sub):
    out = io.StringIO()
    with redirect_stdout(out), pytest.raises(SystemExit) as e:
        cli.main(sub + ["--help"])
    assert e.value.code == 0
    if sub in (["check"], ["export-sphere"], ["generate"]):
        assert "default" in out.getvalue()
