"""Printable sphere: OBJ + MTL + the texture PNG, from the renderer's own mesh generator.

The mesh is sim.mesh.uv_sphere, the one the renderer draws, so a print made
from these files carries the texture exactly where the renderer puts it
(conventions.md texture mapping). Vertices are in millimetres (OBJ has no
unit; the header comment says so). Every file is written under a temporary
name and renamed, so a failed export never leaves half a file.
"""
import math
import os
import re
import shutil

from sim.mesh import uv_sphere

MAX_DIAMETER_MM = 10000.0      # 10 m: far beyond any printer; bigger numbers only bloat the OBJ text
LAT_SEGMENTS = (2, 720)        # a quarter degree at most, finer than any print; at the bound the OBJ is
LON_SEGMENTS = (3, 1440)       # 223 MB, built in memory (1.2 GB peak, 28 s), instead of a MemoryError
# OBJ and MTL name files and materials by whitespace-separated ASCII tokens, and the name becomes a
# file in --out: letters, digits, '.', '_', '-', '+', not starting with '.' or '-'.
_PLAIN_NAME = re.compile(r"[A-Za-z0-9_+][A-Za-z0-9._+-]{0,199}")


class ExportError(ValueError):
    """An argument the export cannot use; the message names the option and the allowed values."""


def plain_name(name):
    """True when name is usable as an OBJ/MTL token and a file name inside the output folder."""
    return bool(_PLAIN_NAME.fullmatch(name))


def check_args(diameter_mm, n_lat, n_lon, name):
    """Raise ExportError for a diameter, segment count or base name the export cannot use."""
    if not (isinstance(diameter_mm, (int, float)) and math.isfinite(diameter_mm)
            and 0.0 < diameter_mm <= MAX_DIAMETER_MM):
        raise ExportError(f"--diameter {diameter_mm}: must be a finite number of millimetres, "
                          f"> 0 and <= {MAX_DIAMETER_MM:g}")
    for opt, n, (lo, hi) in (("--lat-segments", n_lat, LAT_SEGMENTS), ("--lon-segments", n_lon, LON_SEGMENTS)):
        if not (isinstance(n, int) and lo <= n <= hi):
            raise ExportError(f"{opt} {n}: must be a whole number from {lo} to {hi}")
    if name is not None and not plain_name(name):
        raise ExportError(f"--name {name!r}: must be a plain file name (letters, digits, '.', '_', '-', '+'; "
                          f"no folders, no spaces, not starting with '.' or '-'; at most 200 characters)")


def _write_atomic(path, text):
    """Write text to path through a temporary file and a rename."""
    tmp = f"{path}.tmp{os.getpid()}"
    try:
        with open(tmp, "w", encoding="ascii", newline="\n") as f:
            f.write(text)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def _copy_atomic(src, dst):
    """Copy a file through a temporary name and a rename."""
    tmp = f"{dst}.tmp{os.getpid()}"
    try:
        shutil.copyfile(src, tmp)
        os.replace(tmp, dst)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def obj_text(name, texture_file, diameter_mm, n_lat, n_lon):
    """(OBJ text, MTL text) of the textured sphere."""
    verts, normals, tcoords, tris = uv_sphere(diameter_mm / 2.0, n_lat=n_lat, n_lon=n_lon)
    lines = [
        f"# spherepose printable sphere: diameter {diameter_mm:g} mm, units millimetres",
        "# texture mapping: docs/conventions.md (north pole = body +Y, longitude 0 = body +Z)",
        f"# {len(verts)} vertices, {len(tris)} triangles",
        f"mtllib {name}.mtl",
        f"o {name}",
    ]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in verts]
    lines += [f"vt {s:.7f} {t:.7f}" for s, t in tcoords]
    lines += [f"vn {x:.6f} {y:.6f} {z:.6f}" for x, y, z in normals]
    lines.append(f"usemtl {name}")
    lines.append("s 1")
    lines += [f"f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}" for a, b, c in tris + 1]
    mtl = "\n".join([
        f"# spherepose printable sphere material: the texture as diffuse colour",
        f"newmtl {name}",
        "Ka 1.000 1.000 1.000",
        "Kd 1.000 1.000 1.000",
        "Ks 0.000 0.000 0.000",
        "d 1.0",
        "illum 1",
        f"map_Kd {texture_file}",
        "",
    ])
    return "\n".join(lines) + "\n", mtl


def export_sphere(texture_png, diameter_mm, out_dir, n_lat=180, n_lon=360, name=None):
    """Write <name>.obj, <name>.mtl and the texture PNG into out_dir; returns the three paths."""
    check_args(diameter_mm, n_lat, n_lon, name)
    stem = os.path.splitext(os.path.basename(texture_png))[0]
    name = name or re.sub(r"[^A-Za-z0-9._+-]", "_", f"{stem}_sphere").lstrip(".-")[-200:]
    tex_name = os.path.basename(texture_png)
    if not plain_name(tex_name):       # the MTL names it: a texture called "my tex.png" is copied as <name>.png
        tex_name = f"{name}.png"
    os.makedirs(out_dir, exist_ok=True)
    tex_out = os.path.join(out_dir, tex_name)
    if os.path.abspath(tex_out) != os.path.abspath(texture_png):
        _copy_atomic(texture_png, tex_out)
    obj, mtl = obj_text(name, tex_name, diameter_mm, n_lat, n_lon)
    obj_path = os.path.join(out_dir, name + ".obj")
    mtl_path = os.path.join(out_dir, name + ".mtl")
    _write_atomic(mtl_path, mtl)
    _write_atomic(obj_path, obj)
    return obj_path, mtl_path, tex_out
