"""Printable sphere: OBJ + MTL + the texture PNG, from the renderer's own mesh generator.

The mesh is sim.mesh.uv_sphere, the one the renderer draws, so a print made
from these files carries the texture exactly where the renderer puts it
(conventions.md texture mapping). Vertices are in millimetres (OBJ has no
unit; the header comment says so). Every file is written under a temporary
name and renamed, so a failed export never leaves half a file.
"""
import os
import shutil

from sim.mesh import uv_sphere


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
    if not diameter_mm > 0:
        raise ValueError(f"diameter {diameter_mm!r} mm: must be positive")
    os.makedirs(out_dir, exist_ok=True)
    stem = os.path.splitext(os.path.basename(texture_png))[0]
    name = name or f"{stem}_sphere"
    tex_name = os.path.basename(texture_png)
    tex_out = os.path.join(out_dir, tex_name)
    if os.path.abspath(tex_out) != os.path.abspath(texture_png):
        _copy_atomic(texture_png, tex_out)
    obj, mtl = obj_text(name, tex_name, diameter_mm, n_lat, n_lon)
    obj_path = os.path.join(out_dir, name + ".obj")
    mtl_path = os.path.join(out_dir, name + ".mtl")
    _write_atomic(mtl_path, mtl)
    _write_atomic(obj_path, obj)
    return obj_path, mtl_path, tex_out
