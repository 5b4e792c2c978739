import numpy as np
import torch

from sim import pose
from training.rotations import (euler_to_matrix, geodesic_deg, matrix_to_euler, matrix_to_rot6d,
                                rot6d_to_matrix, wrap_deg)


def test_euler_matrix_against_vectors(vectors):
    for case in vectors["cases"]:
        e = torch.tensor(case["pose_deg"], dtype=torch.float64)
        R = torch.tensor(case["R"], dtype=torch.float64)
        assert torch.allclose(euler_to_matrix(e), R, atol=1e-6), case["pose_deg"]
        back = matrix_to_euler(R)
        assert torch.allclose(wrap_deg(back - e), torch.zeros(3, dtype=torch.float64), atol=1e-4), case["pose_deg"]
        # 6-D: two columns, back through Gram-Schmidt to the same matrix
        d6 = matrix_to_rot6d(R)
        assert torch.allclose(d6, torch.cat([R[:, 0], R[:, 1]]))
        assert torch.allclose(rot6d_to_matrix(d6), R, atol=1e-6)
        # a scaled, skewed 6-D vector maps to the same rotation
        skew = torch.cat([2.5 * R[:, 0], 0.7 * R[:, 1] + 0.3 * R[:, 0]])
        assert torch.allclose(rot6d_to_matrix(skew), R, atol=1e-6)


def test_torch_matches_sim_pose_numpy():
    rng = np.random.default_rng(1)
    e = rng.uniform(-60, 60, (50, 3))
    Rt = euler_to_matrix(torch.tensor(e)).numpy()
    for i in range(len(e)):
        assert np.allclose(Rt[i], pose.euler_to_matrix(*e[i]), atol=1e-12)
        assert np.allclose(matrix_to_euler(torch.tensor(Rt[i])).numpy(), pose.matrix_to_euler(Rt[i]), atol=1e-9)
    R6 = rot6d_to_matrix(torch.tensor(rng.normal(size=(50, 6))))
    eye = R6.transpose(-1, -2) @ R6
    assert torch.allclose(eye, torch.eye(3, dtype=eye.dtype).expand_as(eye), atol=1e-9)
    assert torch.allclose(torch.linalg.det(R6), torch.ones(50, dtype=R6.dtype), atol=1e-9)


def test_geodesic_and_gradients():
    a = torch.tensor([[0.0, 0.0, 0.0]])
    b = torch.tensor([[0.0, 0.0, 7.0]])
    assert abs(float(geodesic_deg(euler_to_matrix(a), euler_to_matrix(b))) - 7.0) < 1e-3
    d6 = torch.randn(4, 6, requires_grad=True)
    matrix_to_euler(rot6d_to_matrix(d6)).sum().backward()
    assert torch.isfinite(d6.grad).all()
