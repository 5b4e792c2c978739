"""The numpy projector follows conventions.md."""
import numpy as np

from sim.pose import body_direction
from textures import views


def test_lonlat_inverts_body_direction():
    rng = np.random.default_rng(1)
    lat = rng.uniform(-89, 89, 200)
    lon = rng.uniform(-179, 179, 200)
    d = body_direction(lat, lon).T
    la, lo = views.lonlat_from_direction(d)
    assert np.allclose(la, lat) and np.allclose(lo, lon)


def _quadrant_texture():
    """Lab texture: value 1 where lat > 0 and lon > 0, else 0 (3 channels)."""
    h, w = 90, 180
    lat = 90 - (np.arange(h) + 0.5) * 180 / h
    lon = (np.arange(w) + 0.5) * 360 / w - 180
    t = ((lat[:, None] > 0) & (lon[None, :] > 0)).astype(np.float32)
    return np.repeat(t[..., None], 3, 2)


def test_pose_zero_sees_texture_centre_north_up_not_mirrored():
    size = 16
    v = views.render_views(_quadrant_texture(), np.zeros((1, 3)), size)[0].reshape(-1, 3)[:, 0]
    pts, mask = views.view_points(size)
    upper_right = (pts[:, 0] > 0.2) & (pts[:, 1] > 0.2)
    others = (pts[:, 0] < -0.2) | (pts[:, 1] < -0.2)
    assert np.all(v[upper_right] > 0.99) and np.all(v[others] < 0.01)


def test_y_rotation_brings_negative_longitude_to_the_centre():
    # R = Ry(30): the body point at longitude -30 on the equator faces the camera.
    h, w = 180, 360
    lon = (np.arange(w) + 0.5) - 180
    t = np.repeat(np.repeat(lon[None, :, None], h, 0), 3, 2).astype(np.float32)
    pts, _ = views.view_points(15)
    centre = np.argmin((pts[:, :2] ** 2).sum(1))
    v = views.render_views(t, np.array([[0.0, 30.0, 0.0]]), 15)[0].reshape(-1, 3)[centre, 0]
    assert abs(v + 30.0) < 1.0


def test_pose_grid_is_p1():
    g = views.pose_grid()
    assert g.shape == (9261, 3) and g.min() == -30 and g.max() == 30
