"""Pose conventions shared by every Python part (see docs/conventions.md).

A pose is (x, y, z) in degrees; the body-to-world rotation is
R = Rz(z) @ Ry(y) @ Rx(x), p_W = R @ p_B.
"""
import numpy as np


def rot_x(a_deg):
    """Right-handed rotation about X by a_deg degrees."""
    a = np.radians(a_deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(b_deg):
    """Right-handed rotation about Y by b_deg degrees."""
    b = np.radians(b_deg)
    c, s = np.cos(b), np.sin(b)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(c_deg):
    """Right-handed rotation about Z by c_deg degrees."""
    g = np.radians(c_deg)
    c, s = np.cos(g), np.sin(g)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def euler_to_matrix(x_deg, y_deg, z_deg):
    """Body-to-world rotation matrix R = Rz(z) Ry(y) Rx(x) for a pose in degrees."""
    return rot_z(z_deg) @ rot_y(y_deg) @ rot_x(x_deg)


def matrix_to_euler(R):
    """Pose (x, y, z) in degrees from a rotation matrix; exact for |y| < 90 degrees."""
    R = np.asarray(R, dtype=float)
    y = -np.degrees(np.arcsin(np.clip(R[2, 0], -1.0, 1.0)))
    x = np.degrees(np.arctan2(R[2, 1], R[2, 2]))
    z = np.degrees(np.arctan2(R[1, 0], R[0, 0]))
    return np.array([x, y, z])


def wrap_deg(a):
    """Wrap angles (scalar or array, degrees) into (-180, 180]."""
    a = np.asarray(a, dtype=float)
    w = np.mod(a + 180.0, 360.0) - 180.0
    return np.where(w == -180.0, 180.0, w)


def geodesic_deg(R_a, R_b):
    """Angle in degrees of the rotation R_a^T R_b (independent of the Euler convention)."""
    M = np.asarray(R_a).T @ np.asarray(R_b)
    c = (np.trace(M) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def body_direction(lat_deg, lon_deg):
    """Unit body-frame direction of texture point (latitude, longitude) in degrees.

    The north pole is body +Y, longitude 0 is body +Z, increasing toward body +X.
    """
    phi, lam = np.radians(lat_deg), np.radians(lon_deg)
    return np.array([np.cos(phi) * np.sin(lam), np.sin(phi), np.cos(phi) * np.cos(lam)])
