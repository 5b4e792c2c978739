"""Printable sphere export: OBJ + MTL + PNG round trip."""
import io
from contextlib import redirect_stderr, redirect_stdout

import numpy as np
from PIL import Image

from sim.mesh import uv_sphere
from textures import cli


def _parse_obj(path):
    v, vt, f, mtllib, usemtl = [], [], [], None, None
    for line in path.read_text().splitlines():
        parts = line.split()
        if not parts or parts[0].startswith("#"):
            continue
        if parts[0] == "v":
            v.append([float(x) for x in parts[1:4]])
        elif parts[0] == "vt":
            vt.append([float(x) for x in parts[1:3]])
        elif parts[0] == "f":
            f.append([[int(i) for i in p.split("/")] for p in parts[1:]])
        elif parts[0] == "mtllib":
            mtllib = parts[1]
        elif parts[0] == "usemtl":
            usemtl = parts[1]
    return np.array(v), np.array(vt), np.array(f), mtllib, usemtl


def test_export_round_trip(texture_dir, tmp_path):
    tex = texture_dir / "Texture_3_color.png"
    out = tmp_path / "print"
    buf = io.StringIO()
    with redirect_stdout(buf):
        rc = cli.main(["export-sphere", "--texture", str(tex), "--diameter", "40", "--out", str(out),
                       "--lat-segments", "18", "--lon-segments", "36"])
    assert rc == 0
    obj = out / "Texture_3_color_sphere.obj"
    v, vt, f, mtllib, usemtl = _parse_obj(obj)
    verts, _, tcoords, tris = uv_sphere(20.0, n_lat=18, n_lon=36)
    assert len(v) == len(verts) == 19 * 37 and len(f) == len(tris)
    assert np.allclose(np.linalg.norm(v, axis=1), 20.0, atol=1e-4)
    assert vt.min() >= 0.0 and vt.max() <= 1.0 and np.allclose(vt, tcoords, atol=1e-6)
    assert f.min() >= 1 and f[:, :, 0].max() <= len(v)
    mtl = (out / mtllib).read_text()
    assert f"newmtl {usemtl}" in mtl and "map_Kd Texture_3_color.png" in mtl
    assert (out / "Texture_3_color.png").read_bytes() == tex.read_bytes()
    assert not [p for p in out.iterdir() if ".tmp" in p.name]


def test_export_rejects_non_png_and_bad_diameter(tmp_path):
    jpg = tmp_path / "t.jpg"
    Image.fromarray(np.zeros((64, 128, 3), np.uint8)).save(jpg)
    err = io.StringIO()
    with redirect_stderr(err):
        rc = cli.main(["export-sphere", "--texture", str(jpg), "--diameter", "40", "--out", str(tmp_path / "o")])
    assert rc == 2 and "t.jpg" in err.getvalue() and "PNG" in err.getvalue()
    png = tmp_path / "t.png"
    Image.fromarray(np.zeros((64, 128, 3), np.uint8)).save(png)
    with redirect_stderr(err):
        rc = cli.main(["export-sphere", "--texture", str(png), "--diameter", "-1", "--out", str(tmp_path / "o")])
    assert rc == 2


def _export(*argv):
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        rc = cli.main(["export-sphere", *argv])
    return rc, out.getvalue(), err.getvalue()


def test_export_validates_diameter_name_and_segments(tmp_path):
    """Each bad value: exit 2, a message naming the option, nothing written (no NaN vertices, no file
    outside --out, no MemoryError)."""
    png = tmp_path / "t.png"
    Image.fromarray(np.zeros((64, 128, 3), np.uint8)).save(png)
    out = tmp_path / "work" / "out"
    base = ["--texture", str(png), "--out", str(out)]
    cases = [
        (["--diameter", "inf"], "--diameter"), (["--diameter", "nan"], "--diameter"),
        (["--diameter=-inf"], "--diameter"), (["--diameter", "0"], "--diameter"),
        (["--diameter", "1e300"], "--diameter"),
        (["--diameter", "40", "--name", "../../x"], "--name"), (["--diameter", "40", "--name", "/tmp/x"], "--name"),
        (["--diameter", "40", "--name", ".."], "--name"), (["--diameter", "40", "--name", "a b"], "--name"),
        (["--diameter", "40", "--name", ""], "--name"), (["--diameter", "40", "--name", "t\u00ebx"], "--name"),
        (["--diameter", "40", "--lat-segments", "100000"], "--lat-segments"),
        (["--diameter", "40", "--lat-segments", "1"], "--lat-segments"),
        (["--diameter", "40", "--lon-segments", "100000"], "--lon-segments"),
        (["--diameter", "40", "--lon-segments", "2"], "--lon-segments"),
    ]
    for extra, opt in cases:
        rc, _, err = _export(*base, *extra)
        assert rc == 2 and opt in err and "Traceback" not in err, (extra, err)
    assert not (tmp_path / "work").exists() and not (tmp_path / "x.obj").exists()


def test_export_default_name_from_an_awkward_texture_name(tmp_path):
    """A texture called 'my tëx.png' gives plain OBJ/MTL names: the MTL must be able to name its PNG."""
    png = tmp_path / "my t\u00ebx.png"
    Image.fromarray(np.zeros((64, 128, 3), np.uint8)).save(png)
    out = tmp_path / "o"
    rc, stdout, err = _export("--texture", str(png), "--out", str(out), "--diameter", "40",
                              "--lat-segments", "4", "--lon-segments", "8")
    assert rc == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["my_t_x_sphere.mtl", "my_t_x_sphere.obj",
                                                     "my_t_x_sphere.png"]
    assert "map_Kd my_t_x_sphere.png" in (out / "my_t_x_sphere.mtl").read_text()
