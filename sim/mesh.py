"""The textured sphere mesh, shared by the renderer and the printable-sphere export.

One generator so that what is printed is exactly what is rendered: vertex
positions follow conventions.md (north pole = body +Y, longitude 0 = body +Z,
increasing toward +X) and texture coordinates are (s, t) = (u / width,
1 - v / height) of the equirectangular image, with t = 1 at the top row
(the north pole), as OBJ and VTK expect.
"""
import numpy as np

from sim.pose import body_direction


def uv_sphere(radius_mm, n_lat=180, n_lon=360):
    """Sphere of `radius_mm` as (vertices [V,3] mm, normals [V,3], tcoords [V,2], triangles [T,3]).

    n_lat rings of latitude and n_lon segments of longitude; the seam at
    longitude +-180 has duplicated vertices so texture coordinates do not wrap.
    """
    lats = np.linspace(-90.0, 90.0, n_lat + 1)
    lons = np.linspace(-180.0, 180.0, n_lon + 1)
    lat_g, lon_g = np.meshgrid(lats, lons, indexing="ij")
    dirs = body_direction(lat_g.ravel(), lon_g.ravel()).T  # [V, 3]
    # Exact poles: cos(+-90 deg) is not exactly zero in floating point.
    dirs[np.abs(lat_g.ravel()) == 90.0, 0] = 0.0
    dirs[np.abs(lat_g.ravel()) == 90.0, 2] = 0.0
    s = (lon_g.ravel() + 180.0) / 360.0
    t = (lat_g.ravel() + 90.0) / 180.0
    idx = np.arange((n_lat + 1) * (n_lon + 1)).reshape(n_lat + 1, n_lon + 1)
    a = idx[:-1, :-1].ravel()
    b = idx[:-1, 1:].ravel()
    c = idx[1:, 1:].ravel()
    d = idx[1:, :-1].ravel()
    # Counter-clockwise seen from outside: latitude grows with the row, longitude with the column.
    tri = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    # Drop triangles that collapse at the poles.
    keep = ~((np.isin(tri[:, 0], idx[0]) & np.isin(tri[:, 1], idx[0])) |
             (np.isin(tri[:, 1], idx[-1]) & np.isin(tri[:, 2], idx[-1])))
    tri = tri[keep]
    return radius_mm * dirs, dirs.copy(), np.stack([s, t], 1), tri.astype(np.int64)
