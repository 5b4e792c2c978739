"""Small ONNX models under the model contract (docs/interfaces.md), for the
host tests: a conv / global-average-pool / linear graph with fixed weights,
so that its output depends on every input pixel, plus broken variants.

    python tests/host/make_model.py --variant good --out model.onnx

Variants: good (euler_deg), rotmat (euler_deg + rotmat), nometa (no
spherepose.preprocess), badmeta (preprocess JSON that does not parse),
wrongshape (input [N, 1, S, S]), wrongout (euler_deg [N, 2]), wrongname
(input called "input"), size64 (preprocess size 64, input 64x64), v2 (as good, with
preprocessing sphere-crop-v2).
"""
import argparse
import json
import sys
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from training import preprocess  # noqa: E402

VARIANTS = ["good", "rotmat", "nometa", "badmeta", "wrongshape", "wrongout", "wrongname", "size64", "v2"]


def build(variant="good", seed=7):
    """An onnx.ModelProto of the given variant."""
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r}; choose from {', '.join(VARIANTS)}")
    pp = preprocess.params({"name": preprocess.NAME_V2 if variant == "v2" else preprocess.NAME_V1})
    if variant == "size64":
        pp["size"] = 64
    S = pp["size"]
    cin = 1 if variant == "wrongshape" else 3
    nout = 2 if variant == "wrongout" else 3
    in_name = "input" if variant == "wrongname" else "image"
    rng = np.random.default_rng(seed)
    feats = 16
    w_conv = (rng.standard_normal((feats, cin, 5, 5)) * 0.2).astype(np.float32)
    b_conv = (rng.standard_normal(feats) * 0.1).astype(np.float32)
    w_fc = (rng.standard_normal((feats, nout)) * 20.0).astype(np.float32)
    b_fc = (rng.standard_normal(nout) * 2.0).astype(np.float32)
    inits = [numpy_helper.from_array(w_conv, "w_conv"), numpy_helper.from_array(b_conv, "b_conv"),
             numpy_helper.from_array(w_fc, "w_fc"), numpy_helper.from_array(b_fc, "b_fc")]
    nodes = [
        helper.make_node("Conv", [in_name, "w_conv", "b_conv"], ["c1"], strides=[4, 4], pads=[2, 2, 2, 2]),
        helper.make_node("Relu", ["c1"], ["r1"]),
        helper.make_node("GlobalAveragePool", ["r1"], ["g1"]),
        helper.make_node("Flatten", ["g1"], ["f1"], axis=1),
        helper.make_node("Gemm", ["f1", "w_fc", "b_fc"], ["euler_deg"]),
    ]
    outputs = [helper.make_tensor_value_info("euler_deg", TensorProto.FLOAT, ["N", nout])]
    if variant == "rotmat":
        w_r = (rng.standard_normal((feats, 9)) * 0.3).astype(np.float32)
        inits += [numpy_helper.from_array(w_r, "w_r"),
                  numpy_helper.from_array(np.array([-1, 3, 3], np.int64), "shape_r")]
        nodes += [helper.make_node("MatMul", ["f1", "w_r"], ["m9"]),
                  helper.make_node("Reshape", ["m9", "shape_r"], ["rotmat"])]
        outputs.append(helper.make_tensor_value_info("rotmat", TensorProto.FLOAT, ["N", 3, 3]))
    graph = helper.make_graph(
        nodes, "spherepose_test",
        [helper.make_tensor_value_info(in_name, TensorProto.FLOAT, ["N", cin, S, S])],
        outputs, inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    meta = {
        "spherepose.preprocess": json.dumps(pp, sort_keys=True),
        "spherepose.euler": "R = Rz(z) Ry(y) Rx(x), degrees, body to world",
        "spherepose.ranges": json.dumps({"x": [-30, 30], "y": [-30, 30], "z": [-30, 30]}),
        "spherepose.texture": "test",
        "spherepose.head": "rot6d" if variant == "rotmat" else "euler",
        "spherepose.arch": "tiny_test",
        "spherepose.metrics": "{}",
    }
    if variant == "nometa":
        del meta["spherepose.preprocess"]
    if variant == "badmeta":
        meta["spherepose.preprocess"] = '{"name": "sphere-crop-v1", "size": '
    for k, v in meta.items():
        p = model.metadata_props.add()
        p.key, p.value = k, v
    onnx.checker.check_model(model)
    return model


def write(path, variant="good"):
    onnx.save(build(variant), str(path))
    return Path(path)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--variant", default="good", choices=VARIANTS, help="which model (default: good)")
    ap.add_argument("--out", required=True, help="output .onnx file")
    args = ap.parse_args(argv)
    write(args.out, args.variant)


if __name__ == "__main__":
    main()
