"""The six paper textures: determinism, size, colours, layouts."""
import hashlib

import numpy as np
import pytest

from textures import generate
from textures.palette import PAPER_LAB, SRGB, delta_e2000, srgb8_to_lab


def _digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_generate_writes_six_files_deterministically(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    pa = generate.generate_all(str(a), 256, 128)
    generate.generate_all(str(b), 256, 128)
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(f"Texture_{l}_{v}.png" for l in (1, 2, 3) for v in ("bw", "color"))
    assert len(pa) == 6
    for n in names:
        assert _digest(a / n) == _digest(b / n)
    assert not [p for p in a.iterdir() if ".tmp" in p.name]


def test_default_size_is_2048_by_1024():
    rgb = generate.render(1, "bw")
    assert rgb.shape == (1024, 2048, 3) and rgb.dtype == np.uint8


@pytest.mark.parametrize("level", generate.LEVELS)
def test_colours_and_shared_layout(level):
    bw = generate.render(level, "bw", 1024, 512)
    col = generate.render(level, "color", 1024, 512)
    bw_set = {tuple(c) for c in np.unique(bw.reshape(-1, 3), axis=0)}
    col_set = {tuple(c) for c in np.unique(col.reshape(-1, 3), axis=0)}
    assert bw_set == {SRGB["white"], SRGB["black"]}
    assert col_set == {SRGB[k] for k in ("white", "black", "green", "blue")}
    # Same layout: ink (non-white) pixels coincide.
    assert np.array_equal((bw != 255).any(2), (col != 255).any(2))


def test_srgb_colours_are_near_the_papers_lab():
    for name in ("white", "black", "green"):
        assert delta_e2000(srgb8_to_lab(SRGB[name]), PAPER_LAB[name]) < 1.0
    blue = np.array(SRGB["blue"])
    d = delta_e2000(srgb8_to_lab(blue), PAPER_LAB["blue"])
    assert d < 5.0
    # Nearest in gamut: no neighbouring 8-bit colour is closer.
    for delta in np.array(np.meshgrid([-2, 0, 2], [-2, 0, 2], [-2, 0, 2])).reshape(3, -1).T:
        other = np.clip(blue + delta, 0, 255)
        assert delta_e2000(srgb8_to_lab(other), PAPER_LAB["blue"]) >= d - 1e-9


def _vertical_run_lengths(ink):
    lengths = []
    for c in range(ink.shape[1]):
        d = np.diff(np.concatenate([[0], ink[:, c].astype(np.int8), [0]]))
        lengths += list(np.nonzero(d == -1)[0] - np.nonzero(d == 1)[0])
    return np.array(lengths)


def test_texture1_is_horizontal_stripes_only_and_broken():
    h = 512
    ink = generate.rasterize(generate.layout(1), 2 * h, h) > 0
    # Every vertical run is one stripe's width: no column structure.
    runs = _vertical_run_lengths(ink)
    width_px = generate.STRIPE_WIDTH[1] / 180.0 * h
    assert np.all(np.abs(runs - width_px) <= 1)
    # No stripe is a full latitude circle: each row with ink also has blank.
    rows = ink.any(1)
    assert rows.any() and not ink[rows].all(1).any()


def test_texture2_adds_columns_and_texture3_more_columns_and_short_stripes():
    assert len(generate.COLUMNS_3) > len(generate.COLUMNS_2) > 0
    h = 512
    for level in (2, 3):
        ink = generate.rasterize(generate.layout(level), 2 * h, h) > 0
        width_px = generate.STRIPE_WIDTH[level] / 180.0 * h
        assert _vertical_run_lengths(ink).max() > 3 * width_px     # columns span several stripes
    short = [r for r in generate.layout(3) if (r[3] - r[2]) <= 30.0 and (r[1] - r[0]) < 20.0]
    assert len(short) >= 8


def test_bad_level_and_version_name_the_choices():
    with pytest.raises(ValueError, match="choose one of"):
        generate.layout(4)
    with pytest.raises(ValueError, match="choose one of"):
        generate.render(1, "grey")
