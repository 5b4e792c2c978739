"""ONNX export under the model contract (docs/interfaces.md), checked against PyTorch.

Input `image` float32 [N, 3, S, S]; output `euler_deg` [N, 3] (+ `rotmat`
[N, 3, 3] for the 6-D head); metadata_props spherepose.* as the contract
lists. After writing, Python onnxruntime runs the file on the same inputs as
PyTorch; a difference above `tol_deg` deletes the file and raises.
"""
import copy
import json
import os
from pathlib import Path

import numpy as np
import onnx
import torch

from .models import ExportWrapper, output_names

EULER = "R = Rz(z) Ry(y) Rx(x), degrees, body to world"
OPSET = 17


class ExportMismatch(RuntimeError):
    """ONNX Runtime and PyTorch disagree beyond the tolerance."""


def metadata(config, metrics):
    """The contract's metadata_props as a dict of strings."""
    return {
        "spherepose.preprocess": json.dumps(config["preprocess"], sort_keys=True),
        "spherepose.euler": EULER,
        "spherepose.ranges": json.dumps(config.get("ranges", {"x": [-30, 30], "y": [-30, 30], "z": [-30, 30]})),
        "spherepose.texture": str(config.get("texture") or "unknown"),
        "spherepose.head": config["head"],
        "spherepose.arch": config["arch"],
        "spherepose.metrics": json.dumps(metrics or {}, sort_keys=True),
    }


def read_metadata(path):
    """metadata_props of an ONNX file as a dict."""
    m = onnx.load(str(path), load_external_data=False)
    return {p.key: p.value for p in m.metadata_props}


def onnx_session(path, threads=None, basic=False):
    """A CPU onnxruntime session for an ONNX file (basic=True: only exact graph rewrites)."""
    import onnxruntime as ort
    so = ort.SessionOptions()
    if threads:
        so.intra_op_num_threads = threads
    if basic:
        so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_BASIC
    return ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])


def run_onnx(path_or_session, images, threads=None):
    """Run an ONNX file (or session) on a float32 [N, 3, S, S] array; returns {output name: array}."""
    sess = path_or_session
    if not hasattr(sess, "run"):
        sess = onnx_session(path_or_session, threads)
    names = [o.name for o in sess.get_outputs()]
    return dict(zip(names, sess.run(names, {"image": np.ascontiguousarray(images, np.float32)})))


def set_metadata(path, items):
    """Add or replace metadata_props of an existing ONNX file (atomically: a temporary file
    beside it, then a rename), e.g. the texture of training/refine.py for refinement."""
    path = Path(path)
    m = onnx.load(str(path))
    keep = [(p.key, p.value) for p in m.metadata_props if p.key not in items]
    del m.metadata_props[:]
    for k, v in keep + list(items.items()):
        p = m.metadata_props.add()
        p.key, p.value = k, v
    onnx.checker.check_model(m)
    tmp = path.with_name(path.name + ".tmp")
    try:
        onnx.save(m, str(tmp))
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def record_texture(config):
    """The texture file named in the training dataset's record, when it is still there with the
    same content (sha256), else None."""
    import hashlib
    t = (config.get("dataset_record") or {}).get("texture")
    if not isinstance(t, dict) or not t.get("path") or not Path(t["path"]).is_file():
        return None
    data = Path(t["path"]).read_bytes()
    if t.get("sha256") and hashlib.sha256(data).hexdigest() != t["sha256"]:
        return None
    return t["path"]


def export_onnx(model, config, path, metrics=None, check_inputs=None, tol_deg=1e-4, texture=None):
    """Write `model` (PoseNet, any device) to `path` and check it with onnxruntime.

    check_inputs: float32 [N, 3, S, S] preprocessed images (real frames are the better
    check); random inputs are used when None. texture: the texture's PNG file, carried in the
    metadata for refinement (training/refine.py). Returns the max |difference| in degrees."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    size = config["preprocess"]["size"]
    model = model.to("cpu").eval()
    wrapper = ExportWrapper(model).eval()
    names = output_names(config["head"])
    dummy = torch.zeros(1, 3, size, size)
    tmp = path.with_name(path.name + ".tmp")
    dyn = {"image": {0: "N"}, **{n: {0: "N"} for n in names}}
    torch.onnx.export(wrapper, (dummy,), str(tmp), input_names=["image"], output_names=names,
                      dynamic_axes=dyn, opset_version=OPSET, dynamo=False, do_constant_folding=True)
    m = onnx.load(str(tmp))
    meta = metadata(config, metrics)
    texture = texture or record_texture(config)
    if texture:
        from .refine import META_TEXTURE, texture_png_b64
        meta[META_TEXTURE] = texture_png_b64(texture)
    for k, v in meta.items():
        p = m.metadata_props.add()
        p.key, p.value = k, v
    m.doc_string = f"spherepose pose regressor ({config['arch']}, {config['head']} head)"
    onnx.checker.check_model(m)
    onnx.save(m, str(tmp))
    try:
        if check_inputs is None:
            g = torch.Generator().manual_seed(0)
            check_inputs = torch.randn(4, 3, size, size, generator=g).numpy()
        x = np.asarray(check_inputs, np.float32)
        # The reference is the PyTorch model evaluated in float64, i.e. the function the file
        # should compute; two float32 evaluations (PyTorch's and onnxruntime's) each sit
        # about 1e-4 deg from it for outputs of tens of degrees, so comparing float32 with
        # float32 would test rounding, not the export.
        ref64 = copy.deepcopy(model).double()
        with torch.no_grad():
            ref = {k: v.numpy() for k, v in ref64(torch.from_numpy(x).double()).items()}
            ref32 = model(torch.from_numpy(x))["euler_deg"].numpy()
        got = run_onnx(onnx_session(tmp, torch.get_num_threads(), basic=True), x)
        diff = float(np.abs(got["euler_deg"] - ref["euler_deg"]).max())
        if "rotmat" in ref:
            diff = max(diff, float(np.abs(got["rotmat"] - ref["rotmat"]).max()) * 57.29577951308232)
        if not diff <= tol_deg:
            d32 = float(np.abs(got["euler_deg"] - ref32).max())
            raise ExportMismatch(f"{path}: onnxruntime differs from PyTorch (float64) by {diff:.3g} deg "
                                 f"(float32 PyTorch: {d32:.3g} deg), more than {tol_deg:g}; file not written")
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    os.replace(tmp, path)
    return diff
