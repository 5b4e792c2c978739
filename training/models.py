"""MobileNet pose regressors (torchvision, trained from scratch: weights=None).

Heads:
- 'euler': 3 outputs, scaled by `angle_scale` (half the pose range, 30 deg) so the
  network works on O(1) numbers; output euler_deg [N, 3].
- 'rot6d': 6 outputs (Zhou et al. 2019), Gram-Schmidt to R, R to the conventions'
  Euler angles; outputs euler_deg [N, 3] and rotmat [N, 3, 3]. The bias starts at
  the identity's 6-D vector so training starts near pose (0, 0, 0).
"""
import torch
from torch import nn
import torchvision

from .rotations import matrix_to_euler, rot6d_to_matrix

ARCHS = ("mobilenet_v2", "mobilenet_v3_small", "mobilenet_v3_large")
HEADS = ("euler", "rot6d")


def _backbone(arch, n_out, dropout, width_mult):
    if arch == "mobilenet_v2":
        m = torchvision.models.mobilenet_v2(weights=None, width_mult=width_mult)
        m.classifier = nn.Sequential(nn.Dropout(dropout), nn.Linear(m.last_channel, n_out))
        return m, m.classifier[-1]
    if arch in ("mobilenet_v3_small", "mobilenet_v3_large"):
        m = getattr(torchvision.models, arch)(weights=None, width_mult=width_mult, dropout=dropout)
        m.classifier[-1] = nn.Linear(m.classifier[-1].in_features, n_out)
        return m, m.classifier[-1]
    raise ValueError(f"unknown arch {arch!r}; valid: {', '.join(ARCHS)}")


class PoseNet(nn.Module):
    """MobileNet -> pose. forward(x) returns {'euler_deg': [N,3]} (+ 'rotmat' for rot6d)."""

    def __init__(self, arch="mobilenet_v2", head="euler", angle_scale=30.0, dropout=0.0, width_mult=1.0):
        super().__init__()
        if head not in HEADS:
            raise ValueError(f"unknown head {head!r}; valid: {', '.join(HEADS)}")
        self.arch, self.head = arch, head
        self.net, last = _backbone(arch, 3 if head == "euler" else 6, dropout, width_mult)
        self.register_buffer("angle_scale", torch.tensor(float(angle_scale)))
        nn.init.normal_(last.weight, 0.0, 1e-3)
        with torch.no_grad():
            if head == "rot6d":
                last.bias.copy_(torch.tensor([1.0, 0.0, 0.0, 0.0, 1.0, 0.0]))
            else:
                last.bias.zero_()

    def forward(self, x):
        y = self.net(x)
        if self.head == "euler":
            return {"euler_deg": y * self.angle_scale}
        R = rot6d_to_matrix(y)
        return {"euler_deg": matrix_to_euler(R), "rotmat": R}


class ExportWrapper(nn.Module):
    """Tuple outputs for ONNX: (euler_deg,) or (euler_deg, rotmat)."""

    def __init__(self, model):
        super().__init__()
        self.model = model

    def forward(self, image):
        out = self.model(image)
        if "rotmat" in out:
            return out["euler_deg"], out["rotmat"]
        return out["euler_deg"]


def build(config):
    """PoseNet from a config dict (keys arch, head, angle_scale, dropout, width_mult)."""
    return PoseNet(config["arch"], config["head"], config.get("angle_scale", 30.0),
                   config.get("dropout", 0.0), config.get("width_mult", 1.0))


def output_names(head):
    return ["euler_deg", "rotmat"] if head == "rot6d" else ["euler_deg"]
