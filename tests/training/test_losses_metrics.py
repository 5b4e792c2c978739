import math

import numpy as np
import pytest
import torch

from training import metrics as M
from training.losses import euler_loss, paper_piecewise, pose_loss, pseudo_huber


def test_pseudo_huber_hand_values():
    a = torch.tensor([0.0, 0.5, 1.0, 2.0])
    want = [0.0, math.sqrt(1.25) - 1, math.sqrt(2) - 1, math.sqrt(5) - 1]
    assert torch.allclose(pseudo_huber(a, 1.0), torch.tensor(want), atol=1e-7)
    # delta scales as delta^2 (sqrt(1 + (a/delta)^2) - 1)
    assert float(pseudo_huber(torch.tensor(4.0), 2.0)) == pytest.approx(4 * (math.sqrt(5) - 1), abs=1e-6)


def test_paper_loss_mae_plus_pseudo_huber():
    pred = torch.tensor([[0.5, -2.0, 0.0]])
    true = torch.zeros(1, 3)
    # MAE = 2.5/3; pseudo-Huber mean = (sqrt(1.25) - 1 + sqrt(5) - 1 + 0) / 3
    want = 2.5 / 3 + (math.sqrt(1.25) - 1 + math.sqrt(5) - 1) / 3
    assert float(euler_loss(pred, true)) == pytest.approx(want, abs=1e-6)
    assert float(euler_loss(pred, true, "mae")) == pytest.approx(2.5 / 3, abs=1e-6)


def test_loss_wraps_angle_differences():
    # 179 vs -179 is 2 degrees apart, not 358
    pred, true = torch.tensor([[179.0, 0.0, 0.0]]), torch.tensor([[-179.0, 0.0, 0.0]])
    assert float(euler_loss(pred, true, "mae")) == pytest.approx(2 / 3, abs=1e-5)


def test_paper_piecewise_as_printed():
    a = torch.tensor([0.5, 2.0])
    assert torch.allclose(paper_piecewise(a), torch.tensor([0.25, math.sqrt(5) - 1]))


def test_rot6d_loss_zero_at_truth_and_has_gradient():
    from training.rotations import euler_to_matrix
    true = torch.tensor([[10.0, -20.0, 5.0]])
    R = euler_to_matrix(true).requires_grad_(True)
    out = {"euler_deg": torch.tensor([[10.0, -20.0, 5.0]]), "rotmat": R}
    loss = pose_loss(out, true)
    assert float(loss.detach()) == pytest.approx(0.0, abs=1e-4)
    unknown = pytest.raises(ValueError, match="valid: mae")
    with unknown:
        euler_loss(true, true, "l2")


def _two_point(err, std, n=200):
    """|errors| with population mean err and std std (half err-std, half err+std)."""
    return np.where(np.arange(n) % 2 == 0, err - std, err + std)


def test_metrics_reproduce_paper_table1_texture3_color():
    err, std = [0.284, 0.367, 0.596], [0.211, 0.242, 0.466]
    e = np.stack([_two_point(a, s) for a, s in zip(err, std)], 1)
    rng = np.random.default_rng(0)
    true = rng.uniform(-30, 30, e.shape)
    pred = true + e * np.where(rng.random(e.shape) < 0.5, -1, 1)  # sign does not matter
    m = M.compute(pred, true)
    assert np.allclose(m["err"], err, atol=1e-9)
    assert np.allclose(m["std"], std, atol=1e-9)
    assert round(m["mae"], 3) == 0.416
    assert round(m["rmse"], 3) == 0.545  # the paper prints 0.543; its own Err/Std give 0.545
    assert M.from_err_std(err, std) == pytest.approx((m["mae"], m["rmse"]), abs=1e-9)
    assert np.allclose(np.square(m["rmse_axis"]), np.square(err) + np.square(std))
    assert m["max"] == pytest.approx([a + s for a, s in zip(err, std)])


def test_metrics_hand_values_and_geodesic():
    true = np.zeros((2, 3))
    pred = np.array([[1.0, 0.0, 0.0], [0.0, -3.0, 0.0]])
    m = M.compute(pred, true)
    assert m["err"] == pytest.approx([0.5, 1.5, 0.0])
    assert m["std"] == pytest.approx([0.5, 1.5, 0.0])
    assert m["mae"] == pytest.approx(4 / 6)
    assert m["rmse"] == pytest.approx(math.sqrt(10 / 6))
    assert m["max"] == pytest.approx([1.0, 3.0, 0.0])
    # single-axis rotations: geodesic = that angle
    assert m["geodesic_mean"] == pytest.approx(2.0, abs=1e-6)
    assert m["geodesic_median"] == pytest.approx(2.0, abs=1e-6)
    # wrapping: 180 vs -179.5 is 0.5 deg
    assert M.compute([[180.0, 0, 0]], [[-179.5, 0, 0]])["mae"] == pytest.approx(0.5 / 3)
    with pytest.raises(ValueError):
        M.compute(np.zeros((0, 3)), np.zeros((0, 3)))


def test_table_has_paper_columns():
    m = M.compute([[1.0, 0, 0]], [[0.0, 0, 0]])
    md = M.table([("val", m)])
    assert "| Err_X | Err_Y | Err_Z | Std_X | Std_Y | Std_Z | MAE | RMSE |" in md
    assert "| val | 1.000 | 0.000 |" in md
