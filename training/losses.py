"""The paper's training loss (§3, Eq. 3): MAE + pseudo-Huber, delta = 1 degree.

The paper names the loss "a composite of the mean absolute error and the
Pseudo-Huber loss" and prints Eq. 3 as a piecewise formula (a^2 for a <= delta,
delta^2 (sqrt(1 + (a/delta)^2) - 1) for a > delta), which is discontinuous at
a = delta and omits the MAE term it names. We implement the text and the
protocol (conventions.md, P1: "loss = MAE + pseudo-Huber with delta = 1 deg"):

    L = mean(a) + mean(delta^2 (sqrt(1 + (a / delta)^2) - 1)),  a = |wrap(pred - true)|

over all samples and the three axes, in degrees. `paper_piecewise` is Eq. 3
as printed, kept for comparison.
"""
import torch

from .rotations import DEG, euler_to_matrix, wrap_deg

LOSSES = ("mae+phuber", "paper-piecewise", "mae", "phuber")


def abs_err(pred_deg, true_deg):
    """|wrap(pred - true)| per sample and axis, degrees."""
    return wrap_deg(pred_deg - true_deg).abs()


def pseudo_huber(a, delta=1.0):
    """delta^2 (sqrt(1 + (a/delta)^2) - 1), elementwise."""
    return delta * delta * (torch.sqrt(1.0 + (a / delta) ** 2) - 1.0)


def paper_piecewise(a, delta=1.0):
    """Eq. 3 as printed: a^2 where a <= delta, pseudo-Huber elsewhere (elementwise)."""
    return torch.where(a <= delta, a * a, pseudo_huber(a, delta))


def euler_loss(pred_deg, true_deg, kind="mae+phuber", delta=1.0):
    """Scalar loss on Euler angles (degrees) with wrapped differences."""
    a = abs_err(pred_deg, true_deg)
    if kind == "mae+phuber":
        return a.mean() + pseudo_huber(a, delta).mean()
    if kind == "paper-piecewise":
        return paper_piecewise(a, delta).mean()
    if kind == "mae":
        return a.mean()
    if kind == "phuber":
        return pseudo_huber(a, delta).mean()
    raise ValueError(f"unknown loss {kind!r}; valid: {', '.join(LOSSES)}")


def pose_loss(out, true_deg, kind="mae+phuber", delta=1.0, rotmat_weight=1.0):
    """Loss for a model output dict. Euler head: euler_loss. 6-D head: euler_loss on the
    Euler angles recovered from its matrix, plus rotmat_weight x the mean absolute
    difference of the matrix elements scaled to degrees (x 180/pi; for small errors an
    element difference is an angle in radians), which keeps the gradient well defined
    where the Euler decomposition is flat."""
    loss = euler_loss(out["euler_deg"], true_deg, kind, delta)
    if "rotmat" in out and rotmat_weight:
        R_true = euler_to_matrix(true_deg)
        loss = loss + rotmat_weight * (out["rotmat"] - R_true).abs().mean() * DEG
    return loss
