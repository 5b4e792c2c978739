"""Start a run from the weights of an exported ONNX model (`posetrain train --init MODEL.onnx`).

A shipped model carries no PyTorch checkpoint, and its export folded every
BatchNorm into the convolution before it (weights W', bias b'). To train on
from it, each Conv2d takes W' and its BatchNorm is made to pass the
convolution's output through unchanged, plus b':

1. BatchNorm as identity plus b' (running mean 0, variance 1 - eps, weight 1,
   bias b'): in eval mode the network now computes exactly the ONNX model.
2. One pass over a batch of training crops records, at each BatchNorm, the
   per-channel mean m and variance v of its input.
3. Each BatchNorm gets running mean m, variance v, weight sqrt(v + eps) and
   bias m + b': still the identity plus b' in eval mode, and in train mode,
   where it normalises with the batch's own statistics (close to m and v),
   nearly so. Without step 3 the first training batches would see every
   channel rescaled to unit variance and forget what the model knew.
"""
import onnx
import torch
from onnx import numpy_helper
from torch import nn


class InitError(ValueError):
    """An ONNX model whose weights do not fit this run's network; the message names the file."""


def _conv_weights(path):
    """[(W', b')] of the model's Conv nodes in graph order (execution order), and its Gemm's."""
    try:
        m = onnx.load(str(path))
    except Exception as e:  # onnx raises several kinds for a bad file
        raise InitError(f"{path}: cannot read ONNX model ({e})") from None
    init = {i.name: numpy_helper.to_array(i) for i in m.graph.initializer}
    convs, gemm = [], None
    for node in m.graph.node:
        if node.op_type == "Conv":
            w = init.get(node.input[1])
            b = init.get(node.input[2]) if len(node.input) > 2 else None
            if w is None:
                raise InitError(f"{path}: Conv node {node.name!r} has no constant weights")
            convs.append((w, b))
        elif node.op_type == "Gemm":
            gemm = (init.get(node.input[1]), init.get(node.input[2]))
    return convs, gemm


def _conv_bn_pairs(model):
    """(Conv2d, BatchNorm2d) in module order: in MobileNet every convolution is followed by one."""
    mods = list(model.modules())
    pairs = []
    for i, mod in enumerate(mods):
        if isinstance(mod, nn.Conv2d):
            bn = next((m for m in mods[i + 1:] if isinstance(m, (nn.BatchNorm2d, nn.Conv2d))), None)
            if not isinstance(bn, nn.BatchNorm2d):
                raise InitError(f"convolution {i} of the network has no BatchNorm after it")
            pairs.append((mod, bn))
    return pairs


@torch.no_grad()
def load_onnx_weights(model, path, calib_images):
    """Copy the ONNX model at `path` into `model` (a training.models.PoseNet of the same arch and
    head) as described above; calib_images: normalised float32 [N, 3, S, S] crops for step 2."""
    convs, gemm = _conv_weights(path)
    pairs = _conv_bn_pairs(model)
    if len(convs) != len(pairs):
        raise InitError(f"{path}: {len(convs)} convolutions, this network has {len(pairs)} "
                        "(another arch or width?)")
    fused_bias = []
    for k, ((w, b), (conv, bn)) in enumerate(zip(convs, pairs)):
        if tuple(w.shape) != tuple(conv.weight.shape):
            raise InitError(f"{path}: convolution {k} has shape {tuple(w.shape)}, this network's "
                            f"{tuple(conv.weight.shape)}")
        conv.weight.copy_(torch.from_numpy(w.copy()))
        b = torch.zeros(w.shape[0]) if b is None else torch.from_numpy(b.copy())
        fused_bias.append(b)
        bn.running_mean.zero_()
        bn.running_var.fill_(1.0 - bn.eps)
        bn.weight.fill_(1.0)
        bn.bias.copy_(b)
    lin = model.net.classifier[-1]
    if gemm is None or gemm[0] is None or tuple(gemm[0].shape) != tuple(lin.weight.shape):
        raise InitError(f"{path}: no final layer of shape {tuple(lin.weight.shape)} (another head?)")
    lin.weight.copy_(torch.from_numpy(gemm[0].copy()))
    lin.bias.copy_(torch.from_numpy(gemm[1].copy()))

    stats = {}
    def record(bn):
        def hook(_mod, inputs):
            x = inputs[0].double()
            stats[bn] = (x.mean((0, 2, 3)), x.var((0, 2, 3), unbiased=False))
        return hook
    handles = [bn.register_forward_pre_hook(record(bn)) for _, bn in pairs]
    was_training = model.training
    model.eval()
    try:
        model(calib_images)
    finally:
        for h in handles:
            h.remove()
        model.train(was_training)
    for (_, bn), b in zip(pairs, fused_bias):
        m, v = stats[bn]
        bn.running_mean.copy_(m.float())
        bn.running_var.copy_(v.float())
        bn.weight.copy_(torch.sqrt(v + bn.eps).float())
        bn.bias.copy_((m + b.double()).float())
