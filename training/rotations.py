"""Differentiable rotation conversions in torch, in the conventions' terms.

R = Rz(z) Ry(y) Rx(x), degrees, body to world (docs/conventions.md);
sim/pose.py is the numpy reference these functions are tested against.
The 6-D representation is Zhou et al. 2019: the first two columns of R,
[R00, R10, R20, R01, R11, R21], mapped back to a rotation by Gram-Schmidt.
"""
import math

import torch

DEG = 180.0 / math.pi
# asin's gradient is infinite at +-1; keep it finite (|y| < 90 deg is the conventions' domain)
_ASIN_CLAMP = 1.0 - 1e-7


def wrap_deg(a):
    """Angles (degrees) wrapped into [-180, 180); differentiable (the conventions' (-180, 180]
    differs only at exactly -180, where |difference| is the same)."""
    return torch.remainder(a + 180.0, 360.0) - 180.0


def euler_to_matrix(euler_deg):
    """[..., 3] (x, y, z) degrees -> [..., 3, 3] body-to-world R = Rz(z) Ry(y) Rx(x)."""
    a = euler_deg / DEG
    cx, cy, cz = torch.cos(a[..., 0]), torch.cos(a[..., 1]), torch.cos(a[..., 2])
    sx, sy, sz = torch.sin(a[..., 0]), torch.sin(a[..., 1]), torch.sin(a[..., 2])
    row0 = torch.stack([cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx], -1)
    row1 = torch.stack([sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx], -1)
    row2 = torch.stack([-sy, cy * sx, cy * cx], -1)
    return torch.stack([row0, row1, row2], -2)


def matrix_to_euler(R):
    """[..., 3, 3] rotation -> [..., 3] (x, y, z) degrees; exact for |y| < 90 deg."""
    y = -torch.asin(torch.clamp(R[..., 2, 0], -_ASIN_CLAMP, _ASIN_CLAMP))
    x = torch.atan2(R[..., 2, 1], R[..., 2, 2])
    z = torch.atan2(R[..., 1, 0], R[..., 0, 0])
    return torch.stack([x, y, z], -1) * DEG


def rot6d_to_matrix(d6, eps=1e-8):
    """[..., 6] (first two columns of R, column-major) -> [..., 3, 3] by Gram-Schmidt."""
    a1, a2 = d6[..., 0:3], d6[..., 3:6]
    b1 = a1 / torch.clamp(torch.linalg.vector_norm(a1, dim=-1, keepdim=True), min=eps)
    a2 = a2 - (b1 * a2).sum(-1, keepdim=True) * b1
    b2 = a2 / torch.clamp(torch.linalg.vector_norm(a2, dim=-1, keepdim=True), min=eps)
    b3 = torch.cross(b1, b2, dim=-1)
    return torch.stack([b1, b2, b3], -1)  # columns


def matrix_to_rot6d(R):
    """[..., 3, 3] -> [..., 6]: the first two columns, column-major."""
    return torch.cat([R[..., :, 0], R[..., :, 1]], -1)


def geodesic_deg(R_a, R_b):
    """Angle (degrees) of R_a^T R_b, batched [..., 3, 3] -> [...] (for metrics, not for gradients)."""
    M = R_a.transpose(-1, -2) @ R_b
    c = (M.diagonal(dim1=-2, dim2=-1).sum(-1) - 1.0) / 2.0
    return torch.acos(torch.clamp(c, -1.0, 1.0)) * DEG
